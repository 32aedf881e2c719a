"""The paper's Table 3: policies learned inside each world model, evaluated in the real game.

For every test game: start from the warm-start policy, learn inside the world model from the
simulated human (online imitation, or filtered behaviour cloning of an expert's best imagined
plans), then play the real game 48 times (each of the 24 starts twice, argmax actions). The
figure is the mean real return over games, with a 95% t interval over games.

Filtered BC has two experts, as in the paper. The near-optimal one is go_to_goal under the true
roles (the simulated human). The paper's suboptimal one is an EMMA policy trained on the test game
and stopped before it converged; here it is the warm-start policy after `SUBOPTIMAL_UPDATES`
minibatch steps of behaviour cloning of the near-optimal expert on real episodes of the test game,
sampling its actions. Each record carries the expert's own real return.
"""

from __future__ import annotations

import copy
import time
from dataclasses import asdict

import numpy as np
import torch

from ..messenger.constants import STARTS
from ..messenger.engine import BatchedMessenger
from ..messenger.spec import GameSpec
from ..stats import mean_interval
from ..world.base import WorldModel
from ..world.frozen_text import FrozenTextEncoder
from ..world.imagine import Policy, imagine
from .expert import expert_actions, expert_policy, role_ids
from .imagined_returns import ImaginedReturns, learn_from_imagined_returns
from .learning import (
    Budget,
    evaluate_real,
    expert_labeller,
    fit_labels,
    labelled_states,
    online_imitation_with,
    sampling_policy,
    start_observations,
)
from .policy import HISTORY, EmmaPolicy, stack_history
from .policy import policy_manual as read_policy_manual

TABLE3_GAMES = 30  # games per split in the tables (Table 3, human effort, read-back)
SETTINGS = ("online_il", "filtered_bc", "filtered_bc_suboptimal", "imagined_returns", "warm_start")
SUBOPTIMAL_UPDATES = 10  # behaviour-cloning steps of the suboptimal expert: far from converged (docs/benchmarks.md)


def evenly_spaced_games(total: int, games: int) -> list[int]:
    """The indices of `games` games evenly spaced over a split of `total` (how `lwm agent table3
    --games` picks them)."""
    return [int(g) for g in np.linspace(0, total - 1, min(games, total)).round().astype(int)]


def table3_games(total: int, games: int = TABLE3_GAMES) -> list[int]:
    """`games` of Table 3's 30 games of a split (every k-th of them), so that a shorter run is a
    subset of the tables' games and compares with their records."""
    thirty = evenly_spaced_games(total, TABLE3_GAMES)
    return thirty[:: max(1, len(thirty) // max(games, 1))][:games]


def real_expert_states(game: GameSpec, episodes: int = 48, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Histories [m, 3, 4, 3] and the near-optimal expert's actions along its own real episodes of
    `game` (episode i from start i % 24): what the paper's experts were trained on, the test game."""
    engine = BatchedMessenger()
    engine.reset([game] * episodes, seed * 100_000 + 50_000 + np.arange(episodes), np.arange(episodes) % len(STARTS))
    ids = role_ids(game)
    frames, hist, labels = [engine.compact_observation()], [], []
    while not engine.done.all():
        running = ~engine.done
        actions = expert_actions(frames[-1], ids, len(frames), seed * 100_000 + np.arange(episodes))
        hist.append(stack_history(np.stack(frames[-HISTORY:], axis=1))[running])
        labels.append(actions[running])
        engine.step(actions.astype(np.int64))
        frames.append(engine.compact_observation())
    return np.concatenate(hist), np.concatenate(labels)


def suboptimal_expert(
    warm: EmmaPolicy, game: GameSpec, policy_manual, budget: Budget, seed: int = 0, updates: int = SUBOPTIMAL_UPDATES
) -> EmmaPolicy:
    """The paper's suboptimal expert: an EMMA policy trained on the test game, stopped early (here
    `updates` behaviour-cloning steps from the warm start on the near-optimal expert's real episodes)."""
    expert = copy.deepcopy(warm)
    hist, labels = real_expert_states(game, seed=seed)
    fit_labels(expert, policy_manual, hist, labels, updates, budget.lr, budget.batch, seed)
    return expert


def filtered_behaviour_cloning(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual,
    policy_manual,
    game: GameSpec,
    starts: np.ndarray,
    budget: Budget,
    seed: int = 0,
    expert: Policy | None = None,
) -> float:
    """The expert plans in the world model, `budget.plans_per_start` plans from each start; the
    plans of each start with the highest imagined return are cloned (minibatch steps, as many as
    online imitation takes). expert: an imagination policy (default: the near-optimal expert).
    Returns the mean imagined return of the kept plans."""
    k = budget.plans_per_start
    first = np.repeat(np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3), k, axis=0)
    im = imagine(
        world,
        world_manual,
        first,
        n=len(first),
        policy=expert or expert_policy(game, seed),
        seed=seed,
        constrained=budget.constrained,
    )
    per_start = max(1, int(round(k * budget.keep)))
    # Ties (common: most plans imagine no reward) go to the shorter plan, then the first drawn.
    order = np.lexsort((np.arange(len(first)), im.lengths, -im.returns, np.arange(len(first)) // k))
    keep = order.reshape(-1, k)[:, :per_start].ravel()
    hist, labels = labelled_states(
        im.observations[keep], im.lengths[keep], im.actions.shape[1] - 1, actions=im.actions[keep]
    )
    fit_labels(
        policy, policy_manual, hist, labels, budget.iterations * budget.grad_steps, budget.lr, budget.batch, seed
    )
    return float(im.returns[keep].mean())


def run_game(
    setting: str,
    world: WorldModel,
    warm: EmmaPolicy,
    game: GameSpec,
    manual: list[str],
    encoder: FrozenTextEncoder,
    budget: Budget,
    seed: int = 0,
) -> dict:
    """Learn in imagination for one game (from its 24 start observations) and evaluate in the real
    game."""
    starts = start_observations(game, seed)
    world_manual = world.read_manual(manual, encoder, list(game.triples))
    policy_manual = read_policy_manual(manual, encoder)
    policy = copy.deepcopy(warm)
    began, began_cpu = time.perf_counter(), time.process_time()
    more = {}
    if setting == "imagined_returns":
        cfg = ImaginedReturns()  # always under the game's rules (its own config), whatever the budget says
        log = learn_from_imagined_returns(policy, world, world_manual, policy_manual, starts, cfg, seed)
        more["imagined"] = log[-1]
        more["learner"] = asdict(cfg)
    elif setting == "filtered_bc_suboptimal":
        learnt = suboptimal_expert(warm, game, policy_manual, budget, seed)
        more["expert_return"] = evaluate_real(learnt, game, policy_manual, budget.eval_episodes, seed).mean
        more["expert_updates"] = SUBOPTIMAL_UPDATES
        n = len(starts) * budget.plans_per_start
        filtered_behaviour_cloning(
            policy, world, world_manual, policy_manual, game, starts, budget, seed,
            expert=sampling_policy(learnt, policy_manual, n, torch.Generator().manual_seed(seed)),
        )  # fmt: skip
    elif setting == "online_il":
        online_imitation_with(
            policy, world, world_manual, policy_manual, expert_labeller(game, seed), starts, budget, seed
        )
    elif setting == "filtered_bc":
        filtered_behaviour_cloning(policy, world, world_manual, policy_manual, game, starts, budget, seed)
    elif setting != "warm_start":
        raise ValueError(f"unknown setting {setting!r}")
    learn_s, learn_cpu = time.perf_counter() - began, time.process_time() - began_cpu
    result = evaluate_real(policy, game, policy_manual, budget.eval_episodes, seed)
    return {
        "return": result.mean,
        "wins": result.wins,
        "deaths": result.deaths,
        "learn_seconds": round(learn_s, 2),
        "learn_cpu_seconds": round(learn_cpu, 2),
        **more,
    }


def summarize(returns: list[float]) -> dict:
    """Mean real return over games and its 95% t interval over games (the paper's)."""
    mean, lo, hi = mean_interval(returns)
    return {"mean": mean, "ci95": [lo, hi], "games": len(returns)}


__all__ = ["Budget", "filtered_behaviour_cloning", "run_game", "suboptimal_expert", "summarize"]

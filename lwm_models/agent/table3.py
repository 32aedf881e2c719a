"""The paper's Table 3: policies learned inside each world model, evaluated in the real game.

For every test game: start from the warm-start policy, learn inside the world model from the
simulated human (online imitation, or filtered behaviour cloning of the expert's best imagined
plans), then play the real game 48 times (each of the 24 starts twice, argmax actions). The
figure is the mean real return over games, with a 95% t interval over games.
"""

from __future__ import annotations

import copy
import time

import numpy as np

from ..messenger.spec import GameSpec
from ..stats import mean_interval
from ..world.base import WorldModel
from ..world.frozen_text import FrozenTextEncoder
from ..world.imagine import imagine
from .expert import expert_policy
from .learning import (
    Budget,
    evaluate_real,
    expert_labeller,
    fit_labels,
    labelled_states,
    online_imitation_with,
    start_observations,
)
from .policy import EmmaPolicy
from .policy import policy_manual as read_policy_manual

TABLE3_GAMES = 30  # games per split in the tables (Table 3, human effort, read-back)


def evenly_spaced_games(total: int, games: int) -> list[int]:
    """The indices of `games` games evenly spaced over a split of `total` (how `lwm agent table3
    --games` picks them)."""
    return [int(g) for g in np.linspace(0, total - 1, min(games, total)).round().astype(int)]


def table3_games(total: int, games: int = TABLE3_GAMES) -> list[int]:
    """`games` of Table 3's 30 games of a split (every k-th of them), so that a shorter run is a
    subset of the tables' games and compares with their records."""
    thirty = evenly_spaced_games(total, TABLE3_GAMES)
    return thirty[:: max(1, len(thirty) // max(games, 1))][:games]


def filtered_behaviour_cloning(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual,
    policy_manual,
    game: GameSpec,
    starts: np.ndarray,
    budget: Budget,
    seed: int = 0,
) -> float:
    """The expert plans in the world model, `budget.plans_per_start` plans from each start; the
    plans of each start with the highest imagined return are cloned (minibatch steps, as many as
    online imitation takes). Returns the mean imagined return of the kept plans."""
    k = budget.plans_per_start
    first = np.repeat(np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3), k, axis=0)
    im = imagine(
        world,
        world_manual,
        first,
        n=len(first),
        policy=expert_policy(game, seed),
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
    if setting == "online_il":
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
    }


def summarize(returns: list[float]) -> dict:
    """Mean real return over games and its 95% t interval over games (the paper's)."""
    mean, lo, hi = mean_interval(returns)
    return {"mean": mean, "ci95": [lo, hi], "games": len(returns)}


__all__ = ["Budget", "filtered_behaviour_cloning", "run_game", "summarize"]

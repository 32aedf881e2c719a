"""The paper's Table 3: policies learned inside each world model, evaluated in the real game.

For every test game: start from the warm-start policy, learn inside the world model from the
simulated human (online imitation, or filtered behaviour cloning of the expert's best imagined
plans), then play the real game 48 times (each of the 24 starts twice, argmax actions). The
figure is the mean real return over games, with a 95% interval over games.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass

import numpy as np

from ..messenger.engine import BatchedMessenger
from ..messenger.spec import GameSpec
from ..world.base import WorldModel
from ..world.frozen_text import FrozenTextEncoder
from ..world.imagine import imagine
from ..world.manual import manual_batch
from .expert import expert_policy
from .learning import evaluate_real, expert_labeller, fit_labels, online_imitation_with
from .policy import EmmaPolicy, stack_history


@dataclass
class Budget:
    """What one game's learning may spend (the paper: 2,000 updates of 10 imagined episodes)."""

    updates: int = 20
    episodes: int = 16
    lr: float = 3e-4
    filtered_plans: int = 32  # filtered BC: expert plans imagined per game
    filtered_keep: float = 0.25  # the share with the highest imagined return that is cloned
    eval_episodes: int = 48


def filtered_behaviour_cloning(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual,
    policy_manual,
    game: GameSpec,
    first_obs: np.ndarray,
    budget: Budget,
    seed: int = 0,
) -> float:
    """The expert plans in the world model; the plans with the highest imagined return are cloned.
    Returns the mean imagined return of the kept plans."""
    im = imagine(world, world_manual, first_obs, n=budget.filtered_plans, policy=expert_policy(game, seed), seed=seed)
    keep = np.argsort(-im.returns)[: max(1, int(round(budget.filtered_plans * budget.filtered_keep)))]
    hist, labels = [], []
    for i in keep:
        n = int(im.lengths[i])
        for t in range(1, n):
            hist.append(stack_history(im.observations[i : i + 1, :t])[0])
            labels.append(int(im.actions[i, t]))
    fit_labels(policy, policy_manual, np.stack(hist), np.array(labels), budget.updates, budget.lr)
    return float(im.returns[keep].mean())


def run_game(
    setting: str,
    world: WorldModel,
    kind: str,
    warm: EmmaPolicy,
    game: GameSpec,
    manual: list[str],
    encoder: FrozenTextEncoder,
    budget: Budget,
    seed: int = 0,
) -> dict:
    """Learn in imagination for one game and evaluate in the real game."""
    engine = BatchedMessenger()
    engine.reset([game], [seed])
    first = engine.compact_observation()[0]
    world_manual = manual_batch(kind, manual, encoder, list(game.triples))
    policy_manual = manual_batch("emma", manual, encoder)
    policy = copy.deepcopy(warm)
    began = time.perf_counter()
    if setting == "online_il":
        online_imitation_with(
            policy,
            world,
            world_manual,
            policy_manual,
            expert_labeller(game, seed),
            first,
            budget.updates,
            budget.episodes,
            budget.lr,
            seed,
        )
    elif setting == "filtered_bc":
        filtered_behaviour_cloning(policy, world, world_manual, policy_manual, game, first, budget, seed)
    elif setting != "warm_start":
        raise ValueError(f"unknown setting {setting!r}")
    learn_s = time.perf_counter() - began
    result = evaluate_real(policy, game, policy_manual, budget.eval_episodes, seed)
    return {"return": result.mean, "wins": result.wins, "deaths": result.deaths, "learn_seconds": round(learn_s, 2)}


def summarize(returns: list[float]) -> dict:
    a = np.asarray(returns, dtype=np.float64)
    half = 1.96 * a.std(ddof=1) / np.sqrt(len(a)) if len(a) > 1 else 0.0
    return {"mean": float(a.mean()), "ci95": [float(a.mean() - half), float(a.mean() + half)], "games": len(a)}


__all__ = ["Budget", "filtered_behaviour_cloning", "run_game", "summarize"]

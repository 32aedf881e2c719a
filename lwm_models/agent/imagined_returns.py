"""Learning from the world model's imagined returns alone: no expert, no labels, no controller.

The agent's own policy plans in the world model from each of the game's starts (sampling its
actions); the plans whose imagined return is highest are cloned, and the improved policy plans
again: expert iteration in imagination, the paper's filtered behaviour cloning with the agent as
its own expert. Only the world model's imagined observations, rewards and terminations decide what
is kept, so nothing here knows the game's rules or its roles.

A plan is kept when its imagined return is above `min_return` and among the best `keep` of its
start's plans; the plans kept in earlier rounds stay in the training set (a success found once is
not forgotten when a later round finds none from that start).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..world.base import WorldModel
from ..world.imagine import imagine
from .learning import fit_labels, labelled_states, sampling_policy
from .policy import EmmaPolicy


@dataclass
class ImaginedReturns:
    """How the agent learns from imagined returns."""

    rounds: int = 6  # plan, keep, clone: how many times
    plans_per_start: int = 8  # plans the policy imagines from each start per round
    keep: float = 0.25  # the share of a start's plans (highest imagined return) that may be kept
    min_return: float = 0.0  # ... and only those whose imagined return is above this
    grad_steps: int = 60  # minibatch steps on every kept state after each round
    batch: int = 256
    lr: float = 1e-3
    constrained: bool = False  # imagine under the game's rules (decoding constraints)


def learn_from_imagined_returns(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual,
    policy_manual,
    starts: np.ndarray,
    cfg: ImaginedReturns,
    seed: int = 0,
) -> list[dict]:
    """Improve `policy` in place; one entry a round: the mean imagined return of its plans, how
    many it kept, and the states cloned so far."""
    starts = np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3)
    k = cfg.plans_per_start
    first = np.repeat(starts, k, axis=0)
    per_start = max(1, int(round(k * cfg.keep)))
    hist_all: list[np.ndarray] = []
    labels_all: list[np.ndarray] = []
    log = []
    for r in range(cfg.rounds):
        im = imagine(
            world, world_manual, first, n=len(first), seed=seed * 1_000 + r, constrained=cfg.constrained,
            policy=sampling_policy(policy, policy_manual, len(first), seed * 1_000 + r),
        )  # fmt: skip
        returns = im.returns
        # Best first within each start; ties (common: most plans imagine no reward) to the shorter plan.
        order = np.lexsort((np.arange(len(first)), im.lengths, -returns, np.arange(len(first)) // k))
        best = order.reshape(-1, k)[:, :per_start].ravel()
        kept = best[returns[best] > cfg.min_return]
        if len(kept):
            hist, labels = labelled_states(
                im.observations[kept], im.lengths[kept], im.actions.shape[1] - 1, actions=im.actions[kept]
            )
            hist_all.append(hist)
            labels_all.append(labels)
        if hist_all:
            fit_labels(
                policy, policy_manual, np.concatenate(hist_all), np.concatenate(labels_all), cfg.grad_steps, cfg.lr,
                cfg.batch, seed * 1_000 + r,
            )  # fmt: skip
        log.append({"round": r + 1, "imagined_return": float(returns.mean()), "kept": int(len(kept)),
                    "states": int(sum(len(h) for h in hist_all))})  # fmt: skip
    return log


__all__ = ["ImaginedReturns", "learn_from_imagined_returns"]

"""Learning from the world model's imagined returns alone: no expert, no labels, no controller.

The agent's own policy plans in the world model from each of the game's starts (sampling its
actions); the plans whose imagined return is highest are cloned, and the improved policy plans
again: expert iteration in imagination, the paper's filtered behaviour cloning with the agent as
its own expert. Only the world model's imagined observations, rewards and terminations decide what
is kept, so nothing here knows the game's rules or its roles.

What is cloned of a plan is its prefix up to the step where its imagined return peaks: a plan that
picks up the message and then dies still shows how to reach the message. A prefix is kept when its
return is above `min_return` and it is among the best `keep` of its start's plans (ties to the
shorter); prefixes kept in earlier rounds stay in the training set, so a success found once is not
forgotten when a later round finds none from that start. A share of each round's plans explores:
each of their actions is a uniform one with probability `explore` (a policy that always walks into
the same death never finds the message otherwise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..messenger.constants import NUM_ACTIONS
from ..world.base import WorldModel
from ..world.imagine import Policy, imagine
from .learning import fit_labels, labelled_states, sampling_policy
from .policy import EmmaPolicy


@dataclass
class ImaginedReturns:
    """How the agent learns from imagined returns."""

    rounds: int = 6  # plan, keep, clone: how many times
    plans_per_start: int = 8  # plans the policy imagines from each start per round
    keep: float = 0.25  # the share of a start's plans (highest imagined return) that may be kept
    min_return: float = 0.0  # ... and only those whose imagined return is above this
    explore: float = 0.3  # the chance of a uniform action in an exploring plan
    exploring: float = 0.5  # the share of each round's plans that explore
    grad_steps: int = 60  # minibatch steps on every kept state after each round
    batch: int = 256
    lr: float = 1e-3
    constrained: bool = False  # imagine under the game's rules (decoding constraints)


def peak_prefixes(rewards: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each imagined trajectory's peak return and the observations up to it ([N] each; the first
    peak, 1 observation when nothing is ever earned)."""
    steps = rewards.shape[1]
    valid = np.arange(steps)[None, :] < lengths[:, None]
    cum = np.where(valid, np.cumsum(rewards, axis=1), -np.inf)
    at = cum.argmax(1)
    return cum[np.arange(len(cum)), at], at + 1


def exploring_policy(policy: Policy, n: int, cfg: ImaginedReturns, seed: int) -> Policy:
    """`policy`, but the last share of each start's cfg.plans_per_start trajectories (n in all,
    start by start) take a uniform action with probability cfg.explore at each step."""
    rng = np.random.default_rng(seed)
    k = cfg.plans_per_start
    explorers = np.arange(n) % k >= int(round(k * (1 - cfg.exploring)))

    def act(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
        actions = np.asarray(policy(obs, idx, t)).copy()
        swap = explorers[idx] & (rng.random(len(idx)) < cfg.explore)
        actions[swap] = rng.integers(NUM_ACTIONS, size=int(swap.sum()))
        return actions

    return act


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
    n = len(first)
    for r in range(cfg.rounds):
        round_seed = seed * 1_000 + r
        im = imagine(
            world, world_manual, first, n=n, seed=round_seed, constrained=cfg.constrained,
            policy=exploring_policy(sampling_policy(policy, policy_manual, n, round_seed), n, cfg, round_seed),
        )  # fmt: skip
        peak, upto = peak_prefixes(im.rewards, im.lengths)
        # Best first within each start; ties to the shorter prefix, then the first drawn.
        order = np.lexsort((np.arange(n), upto, -peak, np.arange(n) // k))
        best = order.reshape(-1, k)[:, :per_start].ravel()
        kept = best[peak[best] > cfg.min_return]
        if len(kept):
            hist, labels = labelled_states(im.observations[kept], upto[kept], im.actions.shape[1] - 1,
                                           actions=im.actions[kept])  # fmt: skip
            hist_all.append(hist)
            labels_all.append(labels)
        if hist_all:
            fit_labels(
                policy, policy_manual, np.concatenate(hist_all), np.concatenate(labels_all), cfg.grad_steps, cfg.lr,
                cfg.batch, round_seed,
            )  # fmt: skip
        log.append({"round": r + 1, "imagined_return": float(im.returns.mean()), "kept": int(len(kept)),
                    "kept_return": float(peak[kept].mean()) if len(kept) else None,
                    "states": int(sum(len(h) for h in hist_all))})  # fmt: skip
    return log


__all__ = ["ImaginedReturns", "learn_from_imagined_returns"]

"""Learning from the world model's imagined returns alone: no expert, no labels, no controller.

Policy gradient in imagination (REINFORCE with a baseline). Each round the agent's policy plays
`episodes` imagined episodes from the game's first boards, sampling its actions, and takes a few
gradient steps on them: each imagined state's action is made likelier in proportion to its
advantage, how much the imagined return after it (discounted by `gamma`) beats the mean of the
round's states at the same step, normalised over the round. An entropy bonus keeps it exploring.
Only the world model's imagined observations, rewards and terminations decide what is learnt, so
nothing here knows the game's rules, its roles or a way to play it: the world model, having read
the manual, is the only source of what is good.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..world.base import ManualBatch, WorldModel
from ..world.imagine import imagine
from .learning import imagined_states, sampling_policy
from .policy import EmmaPolicy


@dataclass
class ImaginedReturns:
    """How the agent learns from imagined returns."""

    rounds: int = 30  # imagine, then learn: how many times
    episodes: int = 96  # imagined episodes a round (the game's 24 first boards, 4 each)
    updates: int = 4  # gradient steps a round, each on all of the round's states
    lr: float = 3e-4  # Adam
    gamma: float = 0.95  # discount of the imagined return after a state
    entropy: float = 0.01  # weight of the policy's entropy in the loss
    constrained: bool = False  # imagine under the game's rules (decoding constraints)


def returns_after(rewards: np.ndarray, lengths: np.ndarray, gamma: float) -> np.ndarray:
    """[N, T + 1]: at s, the discounted imagined return of the steps after observation s
    (rewards[:, t] is earned on the step into observation t; nothing after a trajectory's end)."""
    earned = np.where(np.arange(rewards.shape[1])[None, :] < lengths[:, None], rewards, 0.0)
    after = np.zeros_like(earned, dtype=np.float64)
    acc = np.zeros(len(earned))
    for t in range(earned.shape[1] - 1, 0, -1):
        acc = earned[:, t] + gamma * acc
        after[:, t - 1] = acc
    return after


def advantages(returns: np.ndarray, steps: np.ndarray) -> np.ndarray:
    """Each state's return minus the mean return of the states at its step, over their spread."""
    baseline = np.zeros_like(returns)
    for s in np.unique(steps):
        at = steps == s
        baseline[at] = returns[at].mean()
    gain = returns - baseline
    return gain / (gain.std() + 1e-6)


def learn_from_imagined_returns(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual: ManualBatch,
    policy_manual: ManualBatch,
    starts: np.ndarray,
    cfg: ImaginedReturns,
    seed: int = 0,
) -> list[dict]:
    """Improve `policy` in place; one entry a round: the mean imagined return of its episodes."""
    starts = np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3)
    first = starts[np.arange(cfg.episodes) % len(starts)]
    opt = torch.optim.Adam(policy.parameters(), lr=cfg.lr)
    log = []
    for r in range(cfg.rounds):
        round_seed = seed * 1_000 + r
        im = imagine(
            world, world_manual, first, n=len(first), seed=round_seed, constrained=cfg.constrained,
            policy=sampling_policy(policy, policy_manual, len(first), torch.Generator().manual_seed(round_seed)),
        )  # fmt: skip
        hist, _, steps, traj = imagined_states(im, im.actions.shape[1] - 1)
        gain = advantages(returns_after(im.rewards, im.lengths, cfg.gamma)[traj, steps], steps)
        h = torch.from_numpy(np.ascontiguousarray(hist))
        taken = torch.from_numpy(im.actions[traj, steps + 1].astype(np.int64))
        weight = torch.from_numpy(gain).float()
        policy.train()
        for _ in range(cfg.updates):
            logp = F.log_softmax(policy(h, policy.id_values(policy_manual).expand(len(h), -1, -1)), -1)
            entropy = -(logp.exp() * logp).sum(-1).mean()
            loss = -(weight * logp.gather(1, taken[:, None])[:, 0]).mean() - cfg.entropy * entropy
            opt.zero_grad()
            loss.backward()
            opt.step()
        policy.eval()
        log.append({"round": r + 1, "imagined_return": float(im.returns.mean()), "states": len(h)})
    return log


__all__ = ["ImaginedReturns", "advantages", "learn_from_imagined_returns", "returns_after"]

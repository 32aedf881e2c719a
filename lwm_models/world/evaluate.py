"""Evaluation of world models as in the paper (docs/game.md, "What is measured"): teacher-forced
cross-entropy per test split (Table 1), imagination metrics from replayed test episodes (Table 2),
and loss against the length of the history prefix.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ..messenger.constants import (
    ACTION_DELTAS,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    DEFAULT_MAX_STEPS,
    GRID,
    IDENTITIES,
)
from .base import WorldModel
from .constraints import StepRules, rule_breaks
from .imagine import Imagination, imagine
from .tokens import BLOCK, OBS_TOKENS, SLOT_DONE, SLOT_KIND, SLOT_OBS, SLOT_REWARD
from .train import evaluate_loss
from .training_data import SplitTokens

TEST_SPLITS = ("newcombo-test", "newattr-test", "newall-test")


@torch.no_grad()
def loss_by_prefix(
    model: WorldModel, data: SplitTokens, batch: int = 64, limit: int | None = None
) -> dict[str, list[float]]:
    """Mean cross-entropy of each block's tokens by the block's index in its episode (1..32): how
    the loss falls as the model sees more history."""
    model.eval()
    sums = np.zeros((3, 33))
    counts = np.zeros((3, 33))
    for tokens, lengths, manual in data.full_episodes(batch, limit):
        h = model.hidden_states(tokens, model.condition(manual))
        n = tokens.shape[1]
        nxt = np.arange(BLOCK, n)
        for row, (kind, head) in enumerate(
            ((SLOT_OBS, model.obs_head), (SLOT_REWARD, model.reward_head), (SLOT_DONE, model.done_head))
        ):
            pos = nxt[SLOT_KIND[nxt % BLOCK] == kind]
            logits = head(h[:, pos - 1]).float()
            ce = F.cross_entropy(logits.transpose(1, 2), tokens[:, pos], reduction="none").numpy()
            valid = pos[None, :] < (lengths.numpy()[:, None] * BLOCK)
            block_idx = pos // BLOCK
            np.add.at(sums[row], block_idx, (ce * valid).sum(0))
            np.add.at(counts[row], block_idx, valid.sum(0))
    mean = sums / np.maximum(counts, 1)
    steps = [i for i in range(1, 33) if counts[0, i] > 0]
    return {
        "step": steps,
        "obs": [float(mean[0, i]) for i in steps],
        "reward": [float(mean[1, i]) for i in steps],
        "done": [float(mean[2, i]) for i in steps],
        "total": [float(mean[:, i].sum()) for i in steps],
    }


def _positions(obs: np.ndarray, entity_id: int) -> np.ndarray | None:
    """(row, col) of the channel holding `entity_id` in a compact observation, or None."""
    hit = np.flatnonzero(obs[:3, 0] == entity_id)
    return obs[hit[0], 1:].astype(np.int64) if len(hit) else None


def _avatar(obs: np.ndarray) -> np.ndarray | None:
    return obs[3, 1:].astype(np.int64) if obs[3, 0] in (AVATAR_NO_MESSAGE, AVATAR_WITH_MESSAGE) else None


def _reach(movement: str) -> int:
    return 2 if movement == "chaser" else 1


def _near(prev_obs: np.ndarray, action: int, entity_id: int, movement: str) -> bool:
    """Was the entity within collision reach of the avatar's previous cell moved by the action?"""
    avatar = _avatar(prev_obs)
    entity = _positions(prev_obs, entity_id)
    if avatar is None or entity is None:
        return False
    moved = np.clip(avatar + np.array(ACTION_DELTAS[action]), 0, GRID - 1)
    return int(np.abs(moved - entity).sum()) <= _reach(movement)


def consistency_counts(observations: np.ndarray, rewards: np.ndarray, lengths: np.ndarray) -> dict[str, int]:
    """Counts of what no real Messenger transition does, over trajectories [n, T, 4, 3] (rewards
    [n, T], `lengths` valid steps each): an entity channel that changes its identity, an avatar
    that moves more than one cell, an entity that vanishes with reward 0 (in the game an entity
    only leaves with a reward: the message picked up, the goal reached, a death on the message).
    `transitions` and `avatar_moves` are the denominators."""
    obs = np.asarray(observations).astype(np.int64)
    prev, cur = obs[:, :-1], obs[:, 1:]
    valid = np.arange(1, obs.shape[1])[None, :] < np.asarray(lengths)[:, None]  # [n, T-1]
    ent_prev, ent_cur = prev[..., :3, 0], cur[..., :3, 0]
    changed = (ent_prev > 0) & (ent_cur > 0) & (ent_prev != ent_cur)
    vanished = (ent_prev > 0) & (ent_cur == 0) & (np.asarray(rewards)[:, 1:, None] == 0)
    avatar_ids = (AVATAR_NO_MESSAGE, AVATAR_WITH_MESSAGE)
    both = np.isin(prev[..., 3, 0], avatar_ids) & np.isin(cur[..., 3, 0], avatar_ids) & valid
    jump = np.abs(cur[..., 3, 1:] - prev[..., 3, 1:]).sum(-1) > 1
    return {
        "transitions": int(valid.sum()),
        "identity_changes": int((changed & valid[..., None]).sum()),
        "vanished_without_reward": int((vanished & valid[..., None]).sum()),
        "avatar_moves": int(both.sum()),
        "avatar_jumps": int((jump & both).sum()),
    }


@dataclass
class ImaginationMetrics:
    """Table 2 and more, from test episodes replayed in imagination (actions of the real episode).

    delta_dist: mean |imagined - real| avatar-entity Manhattan distance (paper's first column).
    reward_precision, termination_precision: the share of imagined non-zero rewards (ends) with an
        entity of a fitting role in reach (the paper's); recall: the share of the real episodes'
        non-zero rewards (ends) that the imagination has at the same step with the same value.
    reward_without_reach: the share of imagined non-zero rewards with no entity in reach at all.
    identity_change_rate: entity channels changing identity per imagined transition (each of 3
        channels counted); avatar_jump_rate: avatar moves longer than one cell per avatar move;
        vanish_rate: entities vanishing without a reward per transition. Real episodes score 0 on
        these three. transitions, identity_changes, avatar_moves, avatar_jumps: their counts, so
        that a rate comes with what it was measured on (a rate of 0.1% over 18,000 transitions
        is 18 events: a difference of a few is noise).
    rule_breaks_per_step: imagined tokens per step that break one of the game's rules
        (world/constraints.py; 0 for real episodes and under constraints).
    """

    delta_dist: float
    reward_precision: float
    reward_recall: float
    termination_precision: float
    termination_recall: float
    reward_without_reach: float
    identity_change_rate: float
    avatar_jump_rate: float
    vanish_rate: float
    rule_breaks_per_step: float
    reward_steps: int
    real_reward_steps: int
    done_steps: int
    episodes: int
    transitions: int = 0
    identity_changes: int = 0
    avatar_moves: int = 0
    avatar_jumps: int = 0

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def imagination_metrics(
    model: WorldModel,
    data: SplitTokens,
    episodes: int | None = None,
    seed: int = 0,
    batch: int = 64,
    max_steps: int = DEFAULT_MAX_STEPS,
    constrained: bool = False,
) -> ImaginationMetrics:
    """Replay test episodes' actions in imagination from their real first observation (raw
    sampling as in the paper, or under the game's rules if `constrained`)."""
    ds = data.ds
    chosen = np.arange(len(data))
    if episodes is not None and episodes < len(chosen):
        chosen = np.linspace(0, len(chosen) - 1, episodes).round().astype(np.int64)
    score = ImaginationScore(max_steps)
    for lo in range(0, len(chosen), batch):
        idx = chosen[lo : lo + batch]
        real = [ds[int(e)] for e in idx]
        firsts = np.stack([ep.observations[0] for ep in real])
        acts = np.zeros((len(idx), max_steps), dtype=np.int64)
        for i, ep in enumerate(real):
            acts[i, : len(ep.actions) - 1] = ep.actions[1:]
        manual = data.manual_batch(idx)
        im = imagine(
            model, manual, firsts, len(idx), acts, seed=seed + lo, max_steps=max_steps, constrained=constrained
        )
        score.add(im, real)
    return score.metrics()


class ImaginationScore:
    """Table 2's counts over batches of imagined trajectories, each beside the real episode whose
    actions it replayed. Real episodes scored as their own imagination get precision and recall 1
    and no consistency breaks (tests/test_training.py): the checks hold for the game itself."""

    def __init__(self, max_steps: int = DEFAULT_MAX_STEPS) -> None:
        self.max_steps = max_steps
        self.dist_err, self.dist_n = 0.0, 0
        self.reward_ok = self.reward_n = self.done_ok = self.done_n = self.unreached = 0
        self.real_rewards = self.recalled_rewards = self.real_dones = self.recalled_dones = 0
        self.breaks = self.break_steps = self.episodes = 0
        self.counts = dict.fromkeys(
            ("transitions", "identity_changes", "vanished_without_reward", "avatar_moves", "avatar_jumps"), 0
        )

    def add(self, im: Imagination, real: list) -> None:
        """Score imagined trajectories `im` (row i replayed the actions of `real[i]`, an Episode)."""
        for k, v in consistency_counts(im.observations, im.rewards, im.lengths).items():
            self.counts[k] += v
        slots, steps = rule_breaks(im.observations, im.actions, im.rewards, im.dones, im.lengths, self.max_steps)
        self.breaks, self.break_steps = self.breaks + int(slots.sum()), self.break_steps + steps
        self.episodes += len(real)
        for i, ep in enumerate(real):
            entities = [(IDENTITIES[e.identity], e.movement, e.role) for e in ep.game.entities]
            common = min(len(ep.observations), int(im.lengths[i]))
            for t in range(1, common):
                a_real, a_im = _avatar(ep.observations[t]), _avatar(im.observations[i, t])
                if a_real is None or a_im is None:
                    continue
                for eid, _, _ in entities:
                    p_real, p_im = _positions(ep.observations[t], eid), _positions(im.observations[i, t], eid)
                    if p_real is None or p_im is None:
                        continue
                    self.dist_err += abs(int(np.abs(a_im - p_im).sum()) - int(np.abs(a_real - p_real).sum()))
                    self.dist_n += 1
            for t in range(1, common):
                if ep.rewards[t] != 0:
                    self.real_rewards += 1
                    self.recalled_rewards += float(im.rewards[i, t]) == float(ep.rewards[t])
            if ep.dones[-1] and len(ep.observations) - 1 < int(im.lengths[i]):
                self.real_dones += 1
                self.recalled_dones += bool(im.dones[i, len(ep.observations) - 1])
            by_role = {role: (eid, mov) for eid, mov, role in entities}
            for t in range(1, int(im.lengths[i])):
                prev, action, r = im.observations[i, t - 1], int(im.actions[i, t]), float(im.rewards[i, t])
                if r != 0:
                    roles = {-1.0: ("enemy", "goal"), 0.5: ("message",), 1.0: ("goal",)}.get(r, ())
                    self.reward_n += 1
                    self.reward_ok += any(_near(prev, action, *by_role[role]) for role in roles)
                    self.unreached += not any(_near(prev, action, eid, mov) for eid, mov, _ in entities)
                if im.dones[i, t]:
                    self.done_n += 1
                    self.done_ok += t == self.max_steps or any(
                        _near(prev, action, *by_role[role]) for role in ("enemy", "goal")
                    )

    def metrics(self) -> ImaginationMetrics:
        counts = self.counts
        return ImaginationMetrics(
            delta_dist=self.dist_err / max(1, self.dist_n),
            reward_precision=self.reward_ok / max(1, self.reward_n),
            reward_recall=self.recalled_rewards / max(1, self.real_rewards),
            termination_precision=self.done_ok / max(1, self.done_n),
            termination_recall=self.recalled_dones / max(1, self.real_dones),
            reward_without_reach=self.unreached / max(1, self.reward_n),
            identity_change_rate=counts["identity_changes"] / max(1, counts["transitions"]),
            avatar_jump_rate=counts["avatar_jumps"] / max(1, counts["avatar_moves"]),
            vanish_rate=counts["vanished_without_reward"] / max(1, counts["transitions"]),
            rule_breaks_per_step=self.breaks / max(1, self.break_steps),
            reward_steps=self.reward_n,
            real_reward_steps=self.real_rewards,
            done_steps=self.done_n,
            episodes=self.episodes,
            transitions=counts["transitions"],
            identity_changes=counts["identity_changes"],
            avatar_moves=counts["avatar_moves"],
            avatar_jumps=counts["avatar_jumps"],
        )


IMPOSSIBLE_GROUPS = {"identity": (0, 3, 6, 9), "position": (1, 2, 4, 5, 7, 8, 10, 11), "reward": (12,), "done": (13,)}
"""A step's 14 sampled slots by what they say: ids, rows and columns, reward, done."""


@torch.no_grad()
def impossible_mass(
    model: WorldModel,
    data: SplitTokens,
    episodes: int | None = None,
    batch: int = 64,
    max_steps: int = DEFAULT_MAX_STEPS,
) -> dict[str, float]:
    """Teacher-forced on real episodes: the probability the model gives to tokens the game's rules
    forbid after the real history (world/constraints.py), summed over a step's 14 tokens and
    averaged over steps (`per_step`), and the same by slot group. Raw sampling turns this mass into
    impossible imagination (identity changes, vanishings with nothing near, jumps, rewards the
    observation does not show), step after step; a sharper model has less of it."""
    model.eval()
    sums, steps = np.zeros(BLOCK - 1), 0
    for tokens, lengths, manual in data.full_episodes(batch, episodes):
        h = model.hidden_states(tokens, model.condition(manual))
        blocks = tokens.view(len(tokens), -1, BLOCK)
        for b in range(1, blocks.shape[1]):
            rows = torch.nonzero(lengths > b).flatten()
            if not len(rows):
                break
            current = blocks[rows, b]
            at_limit = torch.full((len(rows),), b >= max_steps)
            rules = StepRules(blocks[rows, b - 1, 1 : 1 + OBS_TOKENS], current[:, 0], at_limit)
            sampled: list[torch.Tensor] = []
            for k in range(BLOCK - 1):
                pos = b * BLOCK + 1 + k
                probs = torch.softmax(model.next_token_logits(h[rows, pos - 1], pos).float(), dim=-1)
                sums[k] += float((probs * ~rules.allowed(k, sampled)).sum())
                sampled.append(current[:, 1 + k])
            steps += len(rows)
    per_slot = sums / max(1, steps)
    out = {"per_step": float(per_slot.sum()), "per_slot": [round(float(x), 5) for x in per_slot]}
    out.update({name: float(per_slot[list(slots)].sum()) for name, slots in IMPOSSIBLE_GROUPS.items()})
    return out


def evaluate_model(
    model: WorldModel,
    splits: dict[str, SplitTokens],
    loss_episodes: int | None = None,
    imagination_episodes: int | None = 200,
    seed: int = 0,
    constrained: bool = False,
) -> dict:
    """Table 1 and Table 2 figures for each given split; with `constrained`, Table 2 also under
    the game's rules (`imagination_constrained`), beside the raw figures."""
    results = {}
    for name, data in splits.items():
        entry = {"cross_entropy": evaluate_loss(model, data, limit=loss_episodes)}
        if imagination_episodes != 0:
            entry["imagination"] = imagination_metrics(model, data, imagination_episodes, seed).as_dict()
            entry["impossible_mass"] = impossible_mass(model, data, imagination_episodes)
            if constrained:
                entry["imagination_constrained"] = imagination_metrics(
                    model, data, imagination_episodes, seed, constrained=True
                ).as_dict()
        results[name] = entry
    return results


__all__ = ["TEST_SPLITS", "ImaginationScore", "evaluate_model", "imagination_metrics", "loss_by_prefix", "OBS_TOKENS"]

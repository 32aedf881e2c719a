"""The plan-review agent: in an unseen game it may not act until a person has seen its plan.

It holds a policy, the manual it believes and what it has been taught in this game, but no world
model: it imagines through an imaginer (the world-model server's `/lwm/imagine`, see imaginer.py). A plan
is the policy's imagined trajectory (argmax actions) with K more sampled futures of the same
policy from the same start, so a reviewer sees how sure the plan is. Feedback it learns from:
- a manual (three descriptions) that replaces the one the policy reads (the world-model server's world
  model takes the same manual from /feedback/manual);
- corrections: the right action for states of the shown plan;
- online imitation: rounds of imagined episodes whose states the reviewer labels (DAgger);
- demonstrations: the reviewer's own plans, cloned (filtered behaviour cloning).
A rejected feedback raises FeedbackError and leaves policy, plan and manual unchanged.
"""

from __future__ import annotations

import copy
import itertools
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import LwmError
from ..messenger.constants import CORNERS, NUM_ACTIONS
from ..world.frozen_text import FrozenTextEncoder
from ..world.imagine import Imagination
from ..world.manual import ManualError
from .learning import Budget, LabelledSet, RoundLabeller, fit_labels, online_imitation
from .policy import EmmaPolicy, act, policy_manual, stack_history
from .roles import RoleBelief, believe
from .self_teaching import Ask, Teaching, TeachingResult, teach
from .understood import read_back


class FeedbackError(LwmError, ValueError):
    """Feedback the agent cannot take; its state is unchanged."""


@dataclass
class Plan:
    plan_id: int
    manual_version: int
    actions: list[int]
    observations: list  # compact observations, the first one real
    rewards: list[float]
    dones: list[bool]
    confidence: list[float]
    imagined_return: float
    agreement: list[float] = field(default_factory=list)
    futures: dict = field(default_factory=dict)
    start_step: int = 0
    understood: list = field(default_factory=list)  # per entity: its imagined behaviour (understood.py)

    def to_json(self) -> dict:
        return dict(self.__dict__)

    @property
    def dies(self) -> bool:
        """The shown trajectory ends in death (a -1 reward)."""
        return any(r < 0 for r in self.rewards)


@dataclass
class Correction:
    step: int  # 1-based step of the plan whose action is corrected
    action: int


def start_observations_like(obs: np.ndarray) -> np.ndarray:
    """[24, 4, 3]: the game's 24 starts as seen from its first observation: the four sprites
    (three entities, the avatar) on the four start cells in every order, channel order kept.
    Resetting the game is not acting in it, and this needs not even that."""
    obs = np.asarray(obs, dtype=np.uint8)
    out = np.repeat(obs[None], 24, axis=0)
    for i, cells in enumerate(itertools.permutations(CORNERS)):
        out[i, :, 1:] = np.asarray(cells)
    return out


def plan_from(im: Imagination, plan_id: int, start_step: int = 0) -> Plan:
    """Trajectory 0 is shown; the others are its sampled futures."""
    n = int(im.lengths[0])
    k = len(im.lengths) - 1
    returns = im.returns[1:]
    died = (im.rewards[1:] < 0).any(1) if k else np.zeros(0, dtype=bool)
    won = (im.rewards[1:] >= 1).any(1) if k else np.zeros(0, dtype=bool)
    agreement = []
    for t in range(1, n):
        running = np.flatnonzero(im.lengths[1:] > t) + 1
        same = (im.observations[running, t, 3] == im.observations[0, t, 3]).all(-1)
        agreement.append(round(float(same.mean()) if len(running) else 0.0, 4))
    return Plan(
        plan_id=plan_id,
        manual_version=im.manual_version,
        actions=im.actions[0, 1:n].tolist(),
        observations=im.observations[0, :n].tolist(),
        rewards=im.rewards[0, 1:n].tolist(),
        dones=im.dones[0, 1:n].tolist(),
        confidence=im.confidence()[0, 1:n].round(4).tolist(),
        imagined_return=float(im.returns[0]),
        agreement=agreement,
        futures={
            "k": k,
            "death_share": round(float(died.mean()) if k else 0.0, 4),
            "win_share": round(float(won.mean()) if k else 0.0, 4),
            "return_mean": round(float(returns.mean()) if k else 0.0, 4),
            "return_std": round(float(returns.std()) if k else 0.0, 4),
            "returns": [round(float(r), 4) for r in returns],
            "lengths": [int(x) - 1 for x in im.lengths[1:]],
        },
        start_step=start_step,
        understood=read_back(im.observations, im.rewards, im.lengths),
    )


@dataclass
class PlanReviewAgent:
    policy: EmmaPolicy
    encoder: FrozenTextEncoder | None
    imaginer: object  # ServiceImaginer or LocalImaginer
    manual: list[str]
    max_steps: int = 32
    lr: float = 1e-3
    futures: int = 8
    labelled: LabelledSet = field(default_factory=LabelledSet)
    # The person's corrections in this review: state (history bytes) -> (history, action).
    pinned: dict = field(default_factory=dict)
    belief: RoleBelief | None = None  # what the world model made of the roles (self-teaching)
    taught_manual: tuple = ()  # the manual (and facts) the agent last taught itself from
    # What the person stated of the board's entities (answers to the reading's questions), as
    # (entity, field, value): part of the manual the agent reads.
    facts: tuple = ()

    def __post_init__(self) -> None:
        self._policy_manual = self._encode(self.manual)

    def _encode(self, manual: Sequence[str]):
        if not isinstance(manual, (list, tuple)):
            raise FeedbackError("a manual is a list of 3 descriptions")
        try:
            return policy_manual(list(manual), self.encoder)
        except ManualError as exc:
            raise FeedbackError(str(exc)) from None

    @property
    def policy_manual(self):
        return self._policy_manual

    # ---------------------------------------------------------------- acting
    def id_values(self, n: int) -> torch.Tensor:
        with torch.no_grad():
            return self.policy.id_values(self._policy_manual).expand(n, -1, -1)

    def greedy(self, before: Sequence = ()) -> Callable[[np.ndarray, np.ndarray, int], np.ndarray]:
        """The policy's argmax actions, as an imagination policy; `before`: real observations that
        preceded the imagination's start (the policy reads the last 3)."""
        values = self.id_values(1)
        prefix = np.asarray(before, dtype=np.uint8).reshape(-1, 4, 3)[-2:]

        def policy(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
            if len(prefix):
                obs = np.concatenate([np.broadcast_to(prefix, (len(obs), *prefix.shape)), obs], axis=1)
            return act(self.policy, stack_history(obs), values.expand(len(idx), -1, -1), sample=False)

        return policy

    def act(self, history: Sequence) -> int:
        """The argmax action after the real observations so far."""
        obs = np.asarray(history, dtype=np.uint8)[None]
        return int(act(self.policy, stack_history(obs), self.id_values(1), sample=False)[0])

    def make_plan(
        self, start: np.ndarray, plan_id: int, seed: int = 0, start_step: int = 0, before: Sequence = ()
    ) -> Plan:
        """The policy's trajectory and `futures` more samples of it from `start` ([4, 3]), with
        the time left after `start_step` real steps."""
        start = np.asarray(start, dtype=np.uint8)
        im = self.imaginer.rollout(
            start, self.greedy(before), n=1 + self.futures, max_steps=self.max_steps - start_step, seed=seed
        )
        return plan_from(im, plan_id, start_step)

    def death_risk(self, history: Sequence, horizon: int, samples: int, seed: int = 0) -> float:
        """The share of `samples` imagined futures of the policy, from the last real observation,
        that die within `horizon` steps."""
        im = self.imaginer.rollout(
            np.asarray(history[-1], dtype=np.uint8), self.greedy(history[:-1]), n=samples, max_steps=horizon, seed=seed
        )
        return float((im.rewards < 0).any(1).mean())

    # ---------------------------------------------------------------- feedback
    def set_manual(self, descriptions: Sequence[str], facts: Sequence[dict] = ()) -> None:
        """Language feedback: the policy reads the new manual; `facts`: what the person stated of
        the board's entities with it."""
        self._policy_manual = self._encode(descriptions)  # raises before anything changes
        self.manual = list(descriptions)
        self.facts = tuple(sorted((f["entity"], f["field"], f["value"]) for f in facts))

    @property
    def unread(self) -> bool:
        """The manual (or the facts stated with it) is one the agent has not taught itself from."""
        return self.taught_manual != (tuple(self.manual), self.facts)

    def check_corrections(self, plan: Plan, corrections: Sequence[Correction]) -> None:
        steps = len(plan.actions)
        for c in corrections:
            if not isinstance(c.step, int) or not 1 <= c.step <= steps:
                raise FeedbackError(f"step {c.step} is not in the plan (steps 1..{steps})")
            if not isinstance(c.action, int) or not 0 <= c.action < NUM_ACTIONS:
                raise FeedbackError(f"action {c.action} is not in 0..{NUM_ACTIONS - 1}")

    def correct(self, plan: Plan, corrections: Sequence[Correction], updates: int = 30) -> int:
        """The right action for states of a plan. A person's correction outweighs everything
        learnt before: it replaces any earlier label of the same state, it is kept (pinned) for
        the rest of the review, and the policy is fine-tuned until it takes the corrected action
        in every pinned state (see `hold_corrections`). Returns how many labelled states it has."""
        self.check_corrections(plan, corrections)
        obs = np.asarray(plan.observations, dtype=np.uint8)[None]
        hist = np.stack([stack_history(obs[:, : c.step])[0] for c in corrections])
        actions = np.array([c.action for c in corrections], dtype=np.int64)
        for h, a in zip(hist, actions, strict=True):
            self.pinned[h.tobytes()] = (h, int(a))  # a later correction of the same state wins
        self.labelled = self.labelled.without(hist)
        self.labelled.add(hist, actions)
        self._fit(updates)
        self.hold_corrections()
        return len(self.labelled)

    def hold_corrections(self, max_updates: int = 300) -> bool:
        """Fine-tune, the pinned corrections in every minibatch, until the policy's argmax action
        in each pinned state is the corrected one (at most `max_updates` steps). Called after
        every kind of learning, so that imitation rounds or demonstrations cannot undo what a
        person corrected. True when every correction holds."""
        if not self.pinned:
            return True
        hist = np.stack([h for h, _ in self.pinned.values()])
        want = np.array([a for _, a in self.pinned.values()], dtype=np.int64)
        taught_h, taught_y = self.labelled.arrays() if len(self.labelled) else (hist[:0], want[:0])
        rng = np.random.default_rng(len(self.labelled))
        for round_no in range(max_updates // 10 + 1):
            if (act(self.policy, hist, self.id_values(len(hist)), sample=False) == want).all():
                return True
            if round_no == max_updates // 10:
                return False
            # Each step: every pinned state, weighted as much as a minibatch of what came before.
            k = min(len(taught_y), 64)
            pick = rng.integers(len(taught_y), size=k) if k else np.zeros(0, dtype=np.int64)
            reps = max(1, k // len(want))
            h = np.concatenate([np.repeat(hist, reps, 0), taught_h[pick]])
            y = np.concatenate([np.repeat(want, reps), taught_y[pick]])
            fit_labels(self.policy, self._policy_manual, h, y, 10, self.lr, batch=len(y), seed=round_no)
        return False

    def clone(self, demonstrations: Sequence[dict], updates: int) -> int:
        """Filtered behaviour cloning: the reviewer's plans (observations o_0..o_n, actions)."""
        hist, labels = [], []
        for i, d in enumerate(demonstrations):
            obs = np.asarray(d["observations"], dtype=np.uint8)
            actions = list(d["actions"])
            if len(obs) != len(actions) + 1:
                raise FeedbackError(
                    f"demonstration {i}: {len(obs)} observations need {len(obs) - 1} actions, got {len(actions)}"
                )
            hist += [stack_history(obs[None, : t + 1])[0] for t in range(len(actions))]
            labels += actions
        self.labelled.add(np.stack(hist), np.asarray(labels))
        self._fit(updates)
        self.hold_corrections()
        return len(self.labelled)

    def imitate(
        self,
        label_round: RoundLabeller,
        starts: np.ndarray,
        budget: Budget,
        seed: int = 0,
        should_stop: Callable[[], bool] = lambda: False,
        on_round: Callable[[int, float, int], None] | None = None,
        timings: dict[str, float] | None = None,
    ) -> list[float]:
        """Online imitation through the imaginer from `starts`; labels come from label_round.
        The person's corrections hold afterwards (hold_corrections)."""
        losses = online_imitation(
            self.policy,
            self.imaginer,
            lambda: self._policy_manual,
            label_round,
            starts,
            budget,
            seed,
            self.max_steps,
            self.labelled,
            should_stop,
            on_round,
            timings,
        )
        self.hold_corrections()
        return losses

    def teach_self(
        self,
        starts: np.ndarray,
        teaching: Teaching,
        ask: Ask | None = None,
        seed: int = 0,
        should_stop: Callable[[], bool] = lambda: False,
        on_round: Callable[[int, TeachingResult], None] | None = None,
        fresh: bool = False,
    ) -> TeachingResult:
        """Learn from the world model's reading of the manual (self_teaching.teach), asking `ask`
        (the reviewer) only where the role assignments still in play disagree. The belief carries
        over to the next call unless `fresh` (a new manual is read afresh); what the reviewer
        labelled joins what they taught before, and their corrections hold afterwards."""
        belief = None if fresh else self.belief
        result = teach(
            self.policy, self.imaginer, lambda: self._policy_manual, starts, teaching, ask, seed, belief,
            should_stop, on_round,
        )  # fmt: skip
        self.belief = result.belief
        self.taught_manual = (tuple(self.manual), self.facts)
        if result.taught is not None:
            self.labelled.add(*result.taught)
        self.hold_corrections()
        return result

    def confirmed(self, starts: np.ndarray) -> bool:
        """Facts the person just stated (the same words, an answer more) that confirm what the agent
        acts on: it takes the sharper reading without teaching itself again, since every label it
        made came from the roles and movements the answer confirms. False where the answer changed
        a role or a movement the agent acted on (it must learn again) or the words changed."""
        if self.belief is None or self.taught_manual[:1] != (tuple(self.manual),):
            return False
        read = believe(self.imaginer, starts)
        if read.best()[0] != self.belief.best()[0] or read.movements != self.belief.movements:
            return False
        self.belief = read
        self.taught_manual = (tuple(self.manual), self.facts)
        return True

    def _fit(self, updates: int) -> None:
        h, y = self.labelled.arrays()
        fit_labels(self.policy, self._policy_manual, h, y, updates, self.lr)

    def snapshot(self) -> dict:
        """Everything a rejected feedback must leave unchanged (for tests)."""
        return {
            "manual": list(self.manual),
            "policy": copy.deepcopy(self.policy.state_dict()),
            "labelled": len(self.labelled),
            "pinned": len(self.pinned),
        }


__all__ = ["Budget", "Correction", "FeedbackError", "Plan", "PlanReviewAgent", "plan_from", "start_observations_like"]

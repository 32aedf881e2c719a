"""The plan-review agent: in an unseen game it may not act until a person has seen its plan.

It holds a world model, a policy and the manual it believes. A plan is one imagined trajectory of
the current policy (argmax actions) with its imagined rewards, done flags and the world model's
confidence. Feedback it takes:
- a manual (three descriptions), which replaces the manual both the world model and the policy
  read (language feedback);
- action corrections for steps of the current plan (the expert's labels for those states),
  which the policy is fine-tuned on;
- online imitation with a labeller (the simulated human: go_to_goal reading the true manual).
A rejected feedback raises FeedbackError and leaves policy, plan and manual unchanged.
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..errors import LwmError
from ..messenger.constants import NUM_ACTIONS
from ..world.base import WorldModel
from ..world.frozen_text import FrozenTextEncoder
from ..world.imagine import imagine
from ..world.manual import ManualError, manual_batch
from .learning import Budget, fit_labels, online_imitation_with
from .policy import EmmaPolicy, act, stack_history


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

    def to_json(self) -> dict:
        return dict(self.__dict__)


@dataclass
class Correction:
    step: int  # 1-based step of the plan whose action is corrected
    action: int


@dataclass
class PlanReviewAgent:
    world: WorldModel
    world_kind: str
    policy: EmmaPolicy
    encoder: FrozenTextEncoder | None
    first_obs: np.ndarray
    manual: list[str]
    max_steps: int = 32
    lr: float = 1e-3
    starts: np.ndarray | None = None  # first observations imagination may start from (default: first_obs)
    manual_version: int = 1
    plan: Plan | None = None
    labelled: list[tuple[np.ndarray, int]] = field(default_factory=list)
    _plans: int = 0

    def __post_init__(self) -> None:
        self._set_batches(self.manual)

    def _set_batches(self, manual: Sequence[str]) -> None:
        try:
            self._world_manual = manual_batch(self.world_kind, manual, self.encoder)
            self._policy_manual = manual_batch("emma", manual, self.encoder)
        except ManualError as exc:
            raise FeedbackError(str(exc)) from None

    # ---------------------------------------------------------------- plans
    def make_plan(self, seed: int = 0) -> Plan:
        with torch.no_grad():
            id_values = self.policy.id_values(self._policy_manual)

        def policy(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
            return act(self.policy, stack_history(obs), id_values.expand(len(idx), -1, -1), sample=False)

        im = imagine(
            self.world, self._world_manual, self.first_obs, n=1, policy=policy, max_steps=self.max_steps, seed=seed
        )
        n = int(im.lengths[0])
        self._plans += 1
        self.plan = Plan(
            plan_id=self._plans,
            manual_version=self.manual_version,
            actions=im.actions[0, 1:n].tolist(),
            observations=im.observations[0, :n].tolist(),
            rewards=im.rewards[0, 1:n].tolist(),
            dones=im.dones[0, 1:n].tolist(),
            confidence=im.confidence()[0, 1:n].round(4).tolist(),
            imagined_return=float(im.returns[0]),
        )
        return self.plan

    # ---------------------------------------------------------------- feedback
    def set_manual(self, descriptions: Sequence[str]) -> int:
        """Language feedback: a new manual for the world model and the policy."""
        if not isinstance(descriptions, (list, tuple)):
            raise FeedbackError("a manual is a list of 3 descriptions")
        self._set_batches(list(descriptions))  # raises before anything changes
        self.manual = list(descriptions)
        self.manual_version += 1
        return self.manual_version

    def correct(self, corrections: Sequence[Correction], updates: int = 30) -> int:
        """Action corrections for states of the current plan: the policy is fine-tuned on every
        correction received so far. Returns how many labelled states it now has."""
        if self.plan is None:
            raise FeedbackError("there is no plan to correct yet")
        steps = len(self.plan.actions)
        for c in corrections:
            if not isinstance(c.step, int) or not 1 <= c.step <= steps:
                raise FeedbackError(f"step {c.step} is not in the plan (steps 1..{steps})")
            if not isinstance(c.action, int) or not 0 <= c.action < NUM_ACTIONS:
                raise FeedbackError(f"action {c.action} is not in 0..{NUM_ACTIONS - 1}")
        obs = np.asarray(self.plan.observations, dtype=np.uint8)[None]
        new = [(stack_history(obs[:, : c.step])[0], c.action) for c in corrections]
        self.labelled.extend(new)
        self._fit(self.labelled, updates)
        return len(self.labelled)

    def imitate(
        self, labeller: Callable[[np.ndarray, int], np.ndarray], budget: Budget | None = None, seed: int = 0
    ) -> list[float]:
        """Online imitation in the world model from this episode's first observation (or `starts`),
        with a labeller(observations [n, 4, 3], t) -> actions. Returns the mean loss of each round."""
        return online_imitation_with(
            self.policy,
            self.world,
            self._world_manual,
            self._policy_manual,
            labeller,
            self.first_obs if self.starts is None else self.starts,
            budget or Budget(),
            seed,
            self.max_steps,
        )

    def _fit(self, labelled: list[tuple[np.ndarray, int]], updates: int) -> None:
        fit_labels(
            self.policy,
            self._policy_manual,
            np.stack([h for h, _ in labelled]),
            np.array([a for _, a in labelled]),
            updates,
            self.lr,
        )

    def snapshot(self) -> dict:
        """Everything a rejected feedback must leave unchanged (for tests and the ledger)."""
        return {
            "manual": list(self.manual),
            "manual_version": self.manual_version,
            "plan": None if self.plan is None else self.plan.to_json(),
            "policy": copy.deepcopy(self.policy.state_dict()),
            "labelled": len(self.labelled),
        }

"""The simulated human of the paper, as a reviewer: the expert (go_to_goal) reading the true manual.

It never approves a plan whose shown trajectory dies. It approves at once a safe plan (its
trajectory lives, at most `max_death_share` of its sampled futures die) that reaches
`approve_return`. Otherwise it first teaches the way it was told to (`teach`: online imitation,
labelling every state of each round, or filtered behaviour cloning, its own best plans imagined
through the world-model server), then corrects the plan's actions where the expert would act otherwise, or
asks for another imagination when the expert would act the same. `teach="none"` neither teaches
nor corrects: with `language`, the manual is all it gives (the agent learns from it alone), then
it only approves, rejects or aborts. From the `max_rounds`-th plan on
it approves a safe plan, from two plans later any plan whose trajectory lives, and it aborts
after `max_rounds + 12` plans without one (asking again is cheap: about a second).

With `language`, its first answer in each review is language feedback instead: the true manual
in its own words (descriptions drawn anew from the description pools), which the planner must
re-plan under before anything else is decided.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..messenger.spec import GameSpec
from .agent import start_observations_like
from .expert import expert_actions, expert_policy, role_ids

TEACH = ("online_il", "filtered_bc", "corrections", "none")


@dataclass
class ScriptedReviewer:
    game: GameSpec
    teach: str = "online_il"
    approve_return: float = 1.0  # approve at once a safe plan that imagines at least this return
    max_death_share: float = 0.5  # safe: the trajectory lives and at most this share of futures die
    max_rounds: int = 4  # plans looked at per review segment before approving a safe one or aborting
    max_corrections: int = 8
    seed: int = 0
    plans_per_start: int = 8  # filtered BC: expert plans imagined per start
    keep: float = 0.25  # filtered BC: the share of each start's plans (best imagined return) sent
    language: bool = False  # first answer of each review: the true manual in its own words
    _spoken: set = field(default_factory=set)
    _rounds: dict = field(default_factory=dict)
    _taught: set = field(default_factory=set)

    def __post_init__(self) -> None:
        if self.teach not in TEACH:
            raise ValueError(f"teach must be one of {TEACH}, got {self.teach!r}")
        self.ids = role_ids(self.game)

    def safe(self, plan: dict) -> bool:
        dies = any(r < 0 for r in plan["rewards"])
        return not dies and plan["futures"]["death_share"] <= self.max_death_share

    def review(self, plan: dict, imaginer=None) -> dict:
        """The feedback for a plan (a review_feedback payload)."""
        segment = (plan["review_id"], plan.get("start_step", 0))
        self._rounds[segment] = rounds = self._rounds.get(segment, 0) + 1
        base = {"review_id": plan["review_id"], "plan_id": plan["plan_id"], "reviewer": "scripted"}
        lives = not any(r < 0 for r in plan["rewards"])
        if self.safe(plan) and plan["imagined_return"] >= self.approve_return:
            return {**base, "decision": "approve", "comment": "safe, reaches the goal"}
        if segment not in self._taught and self.teach not in ("corrections", "none"):
            self._taught.add(segment)
            if self.teach == "online_il":
                return {**base, "decision": "imitate"}
            if imaginer is not None:
                return {**base, "decision": "demonstrations", "demonstrations": self.demonstrations(plan, imaginer)}
        if rounds >= self.max_rounds and (self.safe(plan) or (lives and rounds >= self.max_rounds + 2)):
            return {**base, "decision": "approve", "comment": f"its trajectory lives (plan {rounds} of this review)"}
        if rounds >= self.max_rounds + 12:
            return {**base, "decision": "abort", "comment": f"no plan that lives in {rounds} plans"}
        fixes = self.corrections(plan) if self.teach != "none" else []
        if fixes:
            return {**base, "decision": "corrections", "corrections": fixes[: self.max_corrections]}
        why = "imagine again" if self.teach == "none" else "the expert would act the same; imagine again"
        return {**base, "decision": "reject", "comment": why}

    def wants_to_speak(self, plan: dict) -> bool:
        """Language feedback comes first, once per review (before any decision on its plans)."""
        if not self.language or plan["review_id"] in self._spoken:
            return False
        self._spoken.add(plan["review_id"])
        return True

    def answer(self, plan: dict) -> dict | None:
        """The true answer to the first question a plan asks about the manual's reading, as a fact
        (a manual's `facts` item); None when it asks none or one already answered."""
        if not plan.get("questions"):
            return None
        q = plan["questions"][0]
        stated = {(f["entity"], f["field"]) for f in plan.get("facts", [])}
        if (q["entity"], q["field"]) in stated:
            return None
        truth = next(t for t in self.game.triples if t[0] == q["entity"])
        return {"entity": q["entity"], "field": q["field"], "value": truth[1] if q["field"] == "movement" else truth[2]}

    def reworded_manual(self, pools, split: str, current: Sequence[str], seed: int = 0) -> list[str]:
        """The game's true manual (its three triples, in a random order) with descriptions drawn
        from `pools` (lwm_models.text.DescriptionPools), other words than `current` where the
        pools allow it."""
        rng = np.random.default_rng([self.seed, seed, 0x4C414E])  # "LAN": language feedback draws
        triples = list(self.game.triples)
        for _ in range(20):
            manual = list(pools.draw(split, [triples[i] for i in rng.permutation(3)], rng))
            if sorted(manual) != sorted(current):
                return manual
        return manual

    def corrections(self, plan: dict) -> list[dict]:
        obs = np.asarray(plan["observations"], dtype=np.uint8)
        start = plan.get("start_step", 0)
        fixes = []
        for k, a in enumerate(plan["actions"]):
            want = int(expert_actions(obs[k : k + 1], self.ids, start + k + 1, self.seed)[0])
            if want != a:
                fixes.append({"step": k + 1, "action": want})
        return fixes

    def label(self, request: dict) -> dict:
        """Labels for every state of a label request (a labels payload)."""
        obs = np.asarray(request["observations"], dtype=np.uint8)
        steps = np.asarray(request["steps"], dtype=np.int64)
        actions = np.zeros(len(obs), dtype=np.int64)
        for t in np.unique(steps):  # the expert's randomness is per step; label a step's states together
            at = np.flatnonzero(steps == t)
            actions[at] = expert_actions(obs[at], self.ids, int(t) + 1, self.seed)
        return {
            "review_id": request["review_id"],
            "request_id": request["request_id"],
            "states": list(range(len(obs))),
            "actions": actions.tolist(),
            "reviewer": "scripted",
        }

    def demonstrations(self, plan: dict, imaginer) -> list[dict]:
        """Filtered BC: the expert plans in the world model (through the world-model server) from the 24
        starts, and the best plans of each start are sent."""
        starts = start_observations_like(plan["observations"][0])
        k = self.plans_per_start
        first = np.repeat(starts, k, axis=0)
        im = imaginer.rollout(first, expert_policy(self.game, self.seed), n=len(first), seed=self.seed)
        per_start = max(1, int(round(k * self.keep)))
        order = np.lexsort((np.arange(len(first)), im.lengths, -im.returns, np.arange(len(first)) // k))
        keep = order.reshape(-1, k)[:, :per_start].ravel()
        return [
            {
                "observations": im.observations[i, : im.lengths[i]].tolist(),
                "actions": im.actions[i, 1 : im.lengths[i]].tolist(),
            }
            for i in keep
            if im.lengths[i] > 1
        ]


__all__ = ["TEACH", "ScriptedReviewer"]

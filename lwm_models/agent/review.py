"""The review loop, ROS-free: the planner node feeds it messages and executes what it approves.

start() makes the first plan for a game; feedback() takes a review message and answers with the
next plan, or with the plan to execute when approved; report() compares the real execution with
the plan. Every plan, feedback, manual version and report goes to the ledger as it happens.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from safetensors.torch import load_file, save_file

from ..errors import LwmError
from ..ledger import Ledger
from .agent import Correction, FeedbackError, Plan, PlanReviewAgent
from .policy import EmmaPolicy


class ReviewSession:
    def __init__(
        self, agent: PlanReviewAgent, review_id: str, ledger: Ledger | None = None, correction_updates: int = 30
    ) -> None:
        self.agent = agent
        self.review_id = review_id
        self.ledger = ledger
        self.revisions = 0
        self.correction_updates = correction_updates
        self._seed = 0
        self.answered: set[tuple[int, str]] = set()  # (plan_id, decision) already in the ledger

    def _log(self, kind: str, payload: dict) -> None:
        if self.ledger is not None:
            self.ledger.record(self.review_id, kind, payload)

    @classmethod
    def resume(cls, agent: PlanReviewAgent, review_id: str, ledger: Ledger, correction_updates: int = 30):
        """Rebuild a review from its ledger after a restart: manuals and corrections are replayed in
        order (the policy is fine-tuned again, deterministically), the last plan is restored.
        Returns (session, last plan message or None, whether an approved plan still has to run)."""
        session = cls(agent, review_id, None, correction_updates)
        last_plan, approved, seen = None, None, set()
        for record in ledger.history(review_id):
            p = record["payload"]
            if record["kind"] == "manual" and p.get("source") != "env":
                agent.set_manual(p["descriptions"])
            elif record["kind"] == "plan":
                last_plan = p
                agent.plan = Plan(**{k: p[k] for k in Plan.__dataclass_fields__})
                agent._plans = p["plan_id"]
                session._seed = p["plan_id"]
                approved = None
            elif record["kind"] == "feedback":
                seen.add((p["plan_id"], p["decision"]))
                if p["decision"] == "corrections":
                    agent.correct([Correction(c["step"], c["action"]) for c in p["corrections"]], correction_updates)
                    agent.plan = Plan(**{k: last_plan[k] for k in Plan.__dataclass_fields__})
                elif p["decision"] == "approve":
                    approved = last_plan
                if p["decision"] != "approve":
                    session.revisions += 1
            elif record["kind"] == "report":
                approved = None
        session.ledger = ledger
        session.answered = seen
        return session, last_plan, approved

    def plan_message(self, plan: Plan) -> dict:
        return {"review_id": self.review_id, "manual": list(self.agent.manual), **plan.to_json()}

    def start(self) -> dict:
        self._log(
            "manual", {"manual_version": self.agent.manual_version, "descriptions": self.agent.manual, "source": "env"}
        )
        return self._new_plan()

    def _new_plan(self) -> dict:
        plan = self.agent.make_plan(seed=self._seed)
        self._seed += 1
        message = self.plan_message(plan)
        self._log("plan", message)
        return message

    def feedback(self, message: dict) -> tuple[str, dict]:
        """('plan', next plan) or ('execute', approved plan). Raises FeedbackError (state unchanged)
        for feedback that does not fit the current review."""
        plan = self.agent.plan
        if message["review_id"] != self.review_id:
            raise FeedbackError(f"feedback for review {message['review_id']!r}, this is {self.review_id!r}")
        if plan is None or message["plan_id"] != plan.plan_id:
            raise FeedbackError(
                f"feedback for plan {message['plan_id']}, the current plan is {None if plan is None else plan.plan_id}"
            )
        decision = message["decision"]
        if decision == "manual":
            version = self.agent.set_manual(message["manual"])
            self._log("feedback", message)
            self._log("manual", {"manual_version": version, "descriptions": message["manual"], "source": "human"})
        elif decision == "corrections":
            self.agent.correct(
                [Correction(c["step"], c["action"]) for c in message["corrections"]], self.correction_updates
            )
            self._log("feedback", message)
        else:
            self._log("feedback", message)
        # Only feedback the agent took counts as answered: a rejected one may be sent again, fixed.
        self.answered.add((message["plan_id"], decision))
        if decision == "approve":
            return "execute", self.plan_message(plan)
        self.revisions += 1
        return "plan", self._new_plan()

    def report(self, plan: dict, real_observations: list, real_return: float, outcome: str) -> dict:
        """Compare the executed trajectory with the plan: real vs imagined return, first step where
        the observations differ, and the mean distance (cells) between planned and real avatar."""
        planned = np.asarray(plan["observations"])
        real = np.asarray(real_observations)
        common = min(len(planned), len(real))
        differ = [t for t in range(common) if not np.array_equal(planned[t], real[t])]
        gaps = np.abs(planned[:common, 3, 1:].astype(int) - real[:common, 3, 1:].astype(int)).sum(-1)
        message = {
            "review_id": self.review_id,
            "plan_id": plan["plan_id"],
            "real_return": float(real_return),
            "imagined_return": float(plan["imagined_return"]),
            "steps": len(real) - 1,
            "outcome": outcome,
            "divergence": {"first_step": differ[0] if differ else None, "mean_cells": float(gaps.mean())},
            "revisions": self.revisions,
        }
        self._log("report", message)
        return message


def save_policy(policy: EmmaPolicy, directory: str | Path, meta: dict | None = None) -> None:
    import json

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in policy.state_dict().items()}, str(directory / "policy.safetensors"))
    (directory / "config.json").write_text(
        json.dumps(
            {"format": "lwm-emma-policy", "version": 1, "config": policy.config.__dict__, **(meta or {})}, indent=2
        )
    )


def load_policy(directory: str | Path) -> EmmaPolicy:
    import json

    from .policy import PolicyConfig

    directory = Path(directory)
    try:
        config = json.loads((directory / "config.json").read_text())
        policy = EmmaPolicy(PolicyConfig(**config["config"]))
        policy.load_state_dict({k: v.float() for k, v in load_file(str(directory / "policy.safetensors")).items()})
    except (OSError, KeyError, ValueError, RuntimeError) as exc:
        raise LwmError(f"cannot load a policy from {directory}: {exc}") from None
    return policy.eval()


__all__ = ["ReviewSession", "load_policy", "save_policy"]

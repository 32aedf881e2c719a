"""Planner/agent node: a thin adapter between ROS and the review loop of lwm_models.agent.review.

It holds no world model: everything it imagines goes through the world-model server's /lwm/imagine
(step-wise sessions for the policy acting in imagination). It follows the world-model server's manual
version on /lwm/status (a new version re-plans), opens a review for each fresh episode on
/env/state, publishes plans (/planner/plan), label requests (/planner/label_request) and execution
reports (/planner/report), takes /review/feedback and /review/labels, and acts in the real game
through /env/reset and /env/step, closed loop, only after approval. It owns the ledger and answers
/planner/history (the reviews, or one review's records), so a review page on any host reads the
history over ROS, not from the file.

Feedback and labels are taken only when signed by a reviewer the planner trusts (parameters
`keys_file`, `trusted`; lwm_nodes.trust): anything else is reported on /lwm/errors and changes
nothing.
"""

from __future__ import annotations

import sqlite3

from lwm_interfaces.srv import Json

from lwm_models import messages
from lwm_models.agent.imaginer import ServiceImaginer
from lwm_models.agent.learning import Budget
from lwm_models.agent.policy import EmmaPolicy, load_policy
from lwm_models.agent.review import Ports, ReviewConfig, ReviewLoop
from lwm_models.agent.self_teaching import Teaching
from lwm_models.errors import LwmError
from lwm_models.ledger import Ledger
from lwm_models.run_dirs import DEFAULT_LEDGER
from lwm_models.world.frozen_text import FrozenTextEncoder
from lwm_models.world.shipped import SHIPPED_POLICY
from lwm_nodes.common import FEEDBACK, LATCHED, JsonNode, json_caller, run
from lwm_nodes.trust import declare_keyring, verified


class PlannerNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("planner")
        p = self.declare_parameter
        self.declare_threads()
        keyring = declare_keyring(self)  # first: a bad key file stops the node before the models load
        self.policy_dir = p("policy", "").value
        ledger = p("ledger", str(DEFAULT_LEDGER)).value
        self.ledger_path = ledger
        call_timeout = float(p("call_timeout", 30.0).value)
        # Learning rounds imagined under the game's rules too (Table 3: raw learns better).
        constrained_learning = bool(p("constrained_learning", False).value)
        teaching = Teaching(
            rounds=int(p("iterations", Teaching.rounds).value),
            episodes=int(p("episodes", Teaching.episodes).value),
            grad_steps=int(p("grad_steps", Teaching.grad_steps).value),
            per_round=int(p("labels_per_round", Teaching.per_round).value),
            constrained=constrained_learning,
            overlap=bool(p("overlap_learning", Teaching.overlap).value),
        )
        config = ReviewConfig(
            futures=int(p("futures", ReviewConfig.futures).value),
            teaching=teaching,
            budget=Budget(constrained=constrained_learning),
            label_timeout=float(p("label_timeout", ReviewConfig.label_timeout).value),
            risk_threshold=float(p("risk_threshold", ReviewConfig.risk_threshold).value),
            risk_horizon=int(p("risk_horizon", ReviewConfig.risk_horizon).value),
            max_rereviews=int(p("max_rereviews", ReviewConfig.max_rereviews).value),
        )
        imagine = self.create_client(Json, "lwm/imagine")
        # Plans and futures (what a person sees) imagined under the game's rules, or the model's raw
        # samples: with the rules the scripted reviews returned +1.05 against +0.85 (docs/benchmarks.md).
        constrained = bool(p("constrained", True).value)
        self.imaginer = ServiceImaginer(
            json_caller(self, imagine, "imagine_response", call_timeout), constrained=constrained
        )
        ports = Ports(
            publish_plan=self.json_publisher("planner/plan", "plan", LATCHED),
            publish_label_request=self.json_publisher("planner/label_request", "label_request", LATCHED),
            publish_report=self.json_publisher("planner/report", "execution_report", LATCHED),
            env_reset=self._env(json_caller(self, self.create_client(Json, "env/reset"), "env_response", call_timeout)),
            env_step=self._env(json_caller(self, self.create_client(Json, "env/step"), "env_response", call_timeout)),
            log=self.get_logger().info,
            publish_progress=self.json_publisher("planner/progress", "progress", LATCHED),
        )
        # The text model loads now, not on the first uncached description of a language feedback.
        encoder = FrozenTextEncoder().load()
        book = Ledger(ledger)
        # A restarted planner still refuses a replay of feedback it took before: the nonces of the
        # signed records in its ledger (those within the signature window) are taken already.
        for record in book.history():
            signed = record["payload"]
            if record["kind"] in ("feedback", "labels") and "nonce" in signed and "signed_at" in signed:
                keyring.remember(signed["nonce"], signed["signed_at"])
        self.loop = ReviewLoop(self.make_policy, encoder, self.imaginer, ports, book, config)
        self.json_subscription("lwm/status", "status", self.loop.on_status, LATCHED)
        self.json_subscription("env/state", "state", self.loop.on_state, LATCHED)
        on_feedback = verified(
            keyring, "review_feedback", self.resolve_topic_name("review/feedback"), self.loop.on_feedback
        )
        self.json_subscription("review/feedback", "review_feedback", on_feedback, FEEDBACK, acks=True)
        on_labels = verified(keyring, "labels", self.resolve_topic_name("review/labels"), self.loop.on_labels)
        self.json_subscription("review/labels", "labels", on_labels, FEEDBACK, acks=True)
        self.json_service("planner/history", self.on_history)

    def on_history(self, req, res):
        """The reviews in the ledger, or one review's records, read from a read-only connection of
        its own (the review loop writes through another, from its worker thread)."""
        try:
            asked = messages.parse("history_request", req.request)
        except messages.MessageError as exc:
            self.report_error(self.resolve_service_name("planner/history"), exc, req.request)
            res.response = messages.dump("history_response", {"ok": False, "error": str(exc)})
            return res
        try:
            ledger = Ledger(self.ledger_path, read_only=True)
            try:
                if "review_id" in asked:
                    found = {"review_id": asked["review_id"], "records": ledger.history(asked["review_id"])}
                else:
                    found = {"reviews": ledger.summaries()}
            finally:
                ledger.close()
            answer = {"ok": True, "ledger": str(self.ledger_path), **found}
        except (OSError, sqlite3.Error) as exc:
            answer = {"ok": False, "error": f"the ledger cannot be read: {exc}"}
        res.response = messages.dump("history_response", answer)
        return res

    def health(self) -> tuple[str, dict[str, object]]:
        loop = self.loop
        values: dict[str, object] = {"manual version": loop.manual_version, "jobs queued": loop.jobs.qsize()}
        r = loop.review
        if r is None:
            return "waiting for an episode to review", values
        values.update({"review": r.review_id, "phase": r.phase, "plans": r.plans, "revisions": r.revisions})
        values["label request open"] = r.request is not None
        return f"review {r.review_id}: {r.phase}", values

    def make_policy(self) -> EmmaPolicy:
        if self.policy_dir:
            return load_policy(self.policy_dir)
        if (SHIPPED_POLICY / "config.json").is_file():
            return load_policy(SHIPPED_POLICY)
        return EmmaPolicy().eval()

    @staticmethod
    def _env(call):
        def env(payload: dict) -> dict:
            answer = call(payload)
            if not answer.get("ok"):
                raise LwmError(answer.get("error", "the environment refused the request"))
            return messages.validate("state", {"version": 1, **answer["state"]})

        return env

    def close(self) -> None:
        self.loop.close(wait=0.5)


def main() -> int:
    return run(PlannerNode)


if __name__ == "__main__":
    raise SystemExit(main())

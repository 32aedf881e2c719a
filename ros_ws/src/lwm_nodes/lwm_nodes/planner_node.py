"""Planner/agent node: plans in imagination, publishes each plan for review, takes review
feedback, and executes only an approved plan in the real game (through /env/reset and /env/step),
publishing an execution report. Every step of the review goes to the ledger.
"""

from __future__ import annotations

import threading

import numpy as np
from lwm_interfaces.srv import Json

from lwm_models import messages
from lwm_models.agent.agent import PlanReviewAgent
from lwm_models.agent.policy import EmmaPolicy
from lwm_models.agent.review import ReviewSession, load_policy
from lwm_models.ledger import Ledger
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.frozen_text import FrozenTextEncoder
from lwm_models.world.shipped import SHIPPED_POLICY, shipped_checkpoint
from lwm_nodes.common import FEEDBACK, LATCHED, JsonNode, run


class PlannerNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("planner")
        checkpoint = self.declare_parameter("checkpoint", "").value
        policy_dir = self.declare_parameter("policy", "").value
        ledger_path = self.declare_parameter("ledger", "logs/ledger.sqlite").value
        self.step_timeout = float(self.declare_parameter("step_timeout", 10.0).value)
        self.world, config = load_checkpoint(checkpoint or shipped_checkpoint("emma"))
        self.world_kind = config["kind"]
        self.policy_dir = policy_dir
        self.encoder = FrozenTextEncoder()
        self.ledger = Ledger(ledger_path)
        self.session: ReviewSession | None = None
        self.manual: list[str] | None = None
        self.state: dict | None = None
        self.executing = False
        self.publish_plan = self.json_publisher("/planner/plan", "plan", LATCHED)
        self.publish_report = self.json_publisher("/planner/report", "execution_report", LATCHED)
        self.json_subscription("/env/manual", "manual", self.on_env_manual, LATCHED)
        self.json_subscription("/env/state", "state", self.on_state, LATCHED)
        self.pending: list[dict] = []  # feedback that arrived before its review was open
        self.json_subscription("/review/feedback", "review_feedback", self.on_feedback, FEEDBACK)
        self.reset_client = self.create_client(Json, "/env/reset")
        self.step_client = self.create_client(Json, "/env/step")

    def on_env_manual(self, payload: dict) -> None:
        self.manual = payload["descriptions"]
        self.maybe_start()

    def on_state(self, payload: dict) -> None:
        if payload["t"] == 0 and not self.executing:
            self.state = payload
            self.maybe_start()

    def maybe_start(self) -> None:
        """A new review starts when a fresh episode (t = 0) and its manual are both known."""
        if self.manual is None or self.state is None or self.executing:
            return
        review_id = self.state["episode_id"]
        if self.session is not None and self.session.review_id == review_id:
            return
        if self.policy_dir:
            policy = load_policy(self.policy_dir)
        elif (SHIPPED_POLICY / "config.json").is_file():
            policy = load_policy(SHIPPED_POLICY)
        else:
            policy = EmmaPolicy().eval()
        agent = PlanReviewAgent(
            self.world,
            self.world_kind,
            policy,
            self.encoder,
            np.asarray(self.state["observation"], dtype=np.uint8),
            list(self.manual),
        )
        if self.ledger.history(review_id):
            # A restart: rebuild the review from the ledger instead of starting it again.
            self.session, plan, approved = ReviewSession.resume(agent, review_id, self.ledger)
            self.get_logger().info(f"review {review_id} resumed from the ledger at plan {plan and plan['plan_id']}")
            if plan is not None:
                self.publish_plan(plan)
            if approved is not None:
                self.executing = True
                threading.Thread(target=self.execute, args=(approved,), daemon=True).start()
        else:
            self.session = ReviewSession(agent, review_id, self.ledger)
            self.publish_plan(self.session.start())
            self.get_logger().info(f"review {review_id}: plan 1 published")
        for payload in self.pending:
            self.on_feedback(payload)
        self.pending = []

    def on_feedback(self, payload: dict) -> None:
        if self.session is None:
            self.pending.append(payload)
            return
        if (
            payload["review_id"] == self.session.review_id
            and (payload["plan_id"], payload["decision"]) in self.session.answered
        ):
            return  # feedback the ledger already holds (redelivered after a restart)
        if self.executing:
            raise messages.MessageError("a plan is being executed; feedback is closed")
        what, plan = self.session.feedback(payload)
        if what == "plan":
            self.publish_plan(plan)
            self.get_logger().info(f"plan {plan['plan_id']} published after {payload['decision']}")
        else:
            self.executing = True
            threading.Thread(target=self.execute, args=(plan,), daemon=True).start()

    def _call(self, client, request: dict) -> dict:
        import json

        if not client.wait_for_service(timeout_sec=self.step_timeout):
            raise RuntimeError(f"{client.srv_name} is not available")
        response = client.call(Json.Request(request=json.dumps(request)), timeout_sec=self.step_timeout)
        if response is None:
            raise RuntimeError(f"{client.srv_name} did not answer")
        answer = json.loads(response.response)
        if not answer.get("ok"):
            raise RuntimeError(f"{client.srv_name}: {answer.get('error')}")
        return answer["state"]

    def execute(self, plan: dict) -> None:
        """Run the approved actions in the real game (a worker thread: the executor keeps spinning
        so the service responses arrive)."""
        try:
            seed = int(self.session.review_id.rsplit(":", 1)[-1])
            state = self._call(self.reset_client, {"seed": seed})
            observations = [state["observation"]]
            for action in plan["actions"]:
                state = self._call(self.step_client, {"action": int(action)})
                observations.append(state["observation"])
                if state["done"]:
                    break
            report = self.session.report(plan, observations, state["return"], state["outcome"])
            self.publish_report(report)
            self.get_logger().info(f"executed plan {plan['plan_id']}: real return {report['real_return']:+.2f}")
        except Exception as exc:
            self.report_error("execution", exc)
        finally:
            self.executing = False


def main() -> int:
    return run(PlannerNode)


if __name__ == "__main__":
    raise SystemExit(main())

"""LWM simulator node: a language-guided world model serving /lwm/imagine.

Takes manuals from /feedback/manual (language feedback, each a new manual version) and, until the
first feedback, the environment's manual from /env/manual; publishes /lwm/status (latched).
"""

from __future__ import annotations

from lwm_interfaces.srv import Imagine

from lwm_models import messages
from lwm_models.world.simulator import Simulator, error_response
from lwm_nodes.common import LATCHED, JsonNode, run


class SimulatorNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("lwm_simulator")
        checkpoint = self.declare_parameter("checkpoint", "").value
        self.follow_env = self.declare_parameter("follow_env_manual", True).value
        self.sim = Simulator(checkpoint or None)
        self.publish_status = self.json_publisher("/lwm/status", "status", LATCHED)
        self.json_subscription("/feedback/manual", "manual", self.on_feedback, LATCHED)
        self.json_subscription("/env/manual", "manual", self.on_env_manual, LATCHED)
        self.create_service(Imagine, "/lwm/imagine", self.on_imagine)
        self.publish_status(self.sim.status())
        self.get_logger().info(f"model {self.sim.model_name} from {self.sim.checkpoint}")

    def on_feedback(self, payload: dict) -> None:
        version = self.sim.set_manual(payload["descriptions"], payload.get("source", "human"))
        self.get_logger().info(f"manual version {version} from {payload.get('source', 'human')}")
        self.publish_status(self.sim.status())

    def on_env_manual(self, payload: dict) -> None:
        # The environment's manual is the default; it never overrides a human's feedback.
        if self.follow_env and self.sim.manual_source in ("", "env"):
            self.sim.set_manual(payload["descriptions"], "env")
            self.publish_status(self.sim.status())

    def on_imagine(self, req, res):
        try:
            request = messages.parse("imagine_request", req.request)
            res.response = messages.dump("imagine_response", self.sim.imagine(request))
        except Exception as exc:
            self.report_error("/lwm/imagine", exc, req.request)
            res.response = messages.dump("imagine_response", error_response(exc))
        return res


def main() -> int:
    return run(SimulatorNode)


if __name__ == "__main__":
    raise SystemExit(main())

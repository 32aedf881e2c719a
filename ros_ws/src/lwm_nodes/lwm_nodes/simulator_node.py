"""LWM simulator node: the one owner of the world model, serving /lwm/imagine.

It holds the model, the current manual and its version (lwm_models.world.simulator.Simulator).
/feedback/manual is the one way to change the manual (each change a new version); the
environment's manual (/env/manual) is the default for each new game. /lwm/status (latched) says
which manual version is current, so the planner re-plans when it changes. The manual and its
version survive a restart (parameter `state`).
"""

from __future__ import annotations

from lwm_interfaces.srv import Json

from lwm_models.world.simulator import Simulator, serve_json
from lwm_nodes.common import LATCHED, JsonNode, run


class SimulatorNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("lwm_simulator")
        checkpoint = self.declare_parameter("checkpoint", "").value
        self.declare_threads()
        state = self.declare_parameter("state", "").value  # JSON file keeping manual and version
        self.follow_env = self.declare_parameter("follow_env_manual", True).value
        max_sessions = int(self.declare_parameter("max_sessions", 32).value)
        self.sim = Simulator(checkpoint or None, state_path=state or None, max_sessions=max_sessions)
        if self.sim.encoder is not None:
            # A new manual's first uncached text would otherwise load the text model (about 4 s
            # of a language feedback's time to the revised plan, measured).
            self.sim.encoder.load()
        self.publish_status = self.json_publisher("/lwm/status", "status", LATCHED)
        self.json_subscription("/feedback/manual", "manual", self.on_feedback, LATCHED)
        self.json_subscription("/env/manual", "manual", self.on_env_manual, LATCHED)
        self.create_service(Json, "/lwm/imagine", self.on_imagine)
        self.publish_status(self.sim.status())
        self.get_logger().info(
            f"model {self.sim.model_name} from {self.sim.checkpoint}; manual v{self.sim.manual_version}"
        )

    def on_feedback(self, payload: dict) -> None:
        version, changed = self.sim.set_manual(payload["descriptions"], payload.get("source", "human"))
        if changed:
            self.get_logger().info(f"manual version {version} from {payload.get('source', 'human')}")
            self.publish_status(self.sim.status())

    def on_env_manual(self, payload: dict) -> None:
        if not self.follow_env:
            return
        version, changed = self.sim.take_env_manual(payload["descriptions"], payload.get("episode_id", ""))
        if changed:
            self.get_logger().info(f"manual version {version} from the environment ({self.sim.game})")
            self.publish_status(self.sim.status())

    def on_imagine(self, req, res):
        res.response, error = serve_json(self.sim, req.request)
        if error is not None:
            self.report_error("/lwm/imagine", error, req.request)
        return res


def main() -> int:
    return run(SimulatorNode)


if __name__ == "__main__":
    raise SystemExit(main())

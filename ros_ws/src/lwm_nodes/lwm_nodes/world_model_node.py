"""World-model server node: the one owner of the world model, serving /lwm/imagine.

It holds the model, the current manual and its version (lwm_models.world.model_server.WorldModelServer).
/feedback/manual is the one way to change the manual (each change a new version); the
environment's manual (/env/manual) is the default for each new game. /lwm/status (latched) says
which manual version is current, so the planner re-plans when it changes. The manual and its
version survive a restart (parameter `state`).

Concurrent /lwm/imagine calls are served by a pool of executor threads; one-shot calls share the
model's steps (continuous batching, lwm_models.world.imagine_server) in a worker process of the node's
own, so that stepping the model does not compete for this process's GIL with the threads that
receive and answer calls. SERVICE_THREADS bounds how many calls wait at once.
"""

from __future__ import annotations

from lwm_interfaces.srv import Json
from rclpy.callback_groups import ReentrantCallbackGroup

from lwm_models.world.imagine_server import WorkerImagineServer
from lwm_models.world.model_server import WorldModelServer
from lwm_nodes.common import LATCHED, JsonNode, run
from lwm_nodes.trust import declare_keyring, verified

SERVICE_THREADS = 16  # executor threads of the node: calls that can wait for a batch at once


class SimulatorNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("lwm_world_model")
        checkpoint = self.declare_parameter("checkpoint", "").value
        threads = self.declare_threads()
        state = self.declare_parameter("state", "").value  # JSON file keeping manual and version
        self.follow_env = self.declare_parameter("follow_env_manual", True).value
        max_sessions = int(self.declare_parameter("max_sessions", 32).value)
        self.sim = WorldModelServer(checkpoint or None, state_path=state or None, max_sessions=max_sessions)
        if self.sim.encoder is not None:
            # A new manual's first uncached text would otherwise load the text model (about 4 s
            # of a language feedback's time to the revised plan, measured).
            self.sim.encoder.load()
        self.publish_status = self.json_publisher("/lwm/status", "status", LATCHED)
        # A manual from a person counts only if a reviewer it trusts signed it (keys_file, trusted).
        on_feedback = verified(declare_keyring(self), "manual", "/feedback/manual", self.on_feedback)
        self.json_subscription("/feedback/manual", "manual", on_feedback, LATCHED, acks=True)
        self.json_subscription("/env/manual", "manual", self.on_env_manual, LATCHED)
        max_rows = int(self.declare_parameter("max_batch_trajectories", 256).value)
        workers = int(self.declare_parameter("imagine_workers", 1).value)  # processes imagining one-shot calls
        self.server = WorkerImagineServer(self.sim, max_rows, threads, workers)
        self.create_service(Json, "/lwm/imagine", self.on_imagine, callback_group=ReentrantCallbackGroup())
        self.publish_status(self.sim.status())
        self.get_logger().info(
            f"model {self.sim.model_name} from {self.sim.checkpoint}; manual v{self.sim.manual_version}"
        )

    def on_feedback(self, payload: dict) -> str:
        version, changed = self.sim.set_manual(payload["descriptions"], payload.get("source", "human"))
        if not changed:
            return f"the same manual as version {version}: nothing changes"
        self.get_logger().info(f"manual version {version} from {payload.get('source', 'human')}")
        self.publish_status(self.sim.status())
        said = f"manual version {version} taken: the world model reads it and the agent re-plans"
        note = self.sim.ungrounded()
        if note is not None:
            said += f"; but {note}"
        return said

    def on_env_manual(self, payload: dict) -> None:
        if not self.follow_env:
            return
        version, changed = self.sim.take_env_manual(payload["descriptions"], payload.get("episode_id", ""))
        if changed:
            self.get_logger().info(f"manual version {version} from the environment ({self.sim.game})")
            self.publish_status(self.sim.status())

    def close(self) -> None:
        self.server.close()

    def on_imagine(self, req, res):
        res.response, error = self.server.serve(req.request)
        if error is not None:
            self.report_error("/lwm/imagine", error, req.request)
        return res


def main() -> int:
    return run(SimulatorNode, threads=SERVICE_THREADS)


if __name__ == "__main__":
    raise SystemExit(main())

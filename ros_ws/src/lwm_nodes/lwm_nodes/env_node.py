"""Messenger environment node: the real game.

Publishes /env/state after every reset and step and the game's manual on /env/manual (latched);
serves /env/reset and /env/step (lwm_interfaces/srv/Json: JSON in, JSON out; schemas
env_reset_request, env_step_request and env_response).
"""

from __future__ import annotations

from lwm_models import messages
from lwm_models.data.session import GameSession
from lwm_models.errors import LwmError
from lwm_nodes.common import LATCHED, JsonNode, run


class EnvNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("messenger_env")
        split = self.declare_parameter("split", "newall-test").value
        index = self.declare_parameter("index", 0).value
        seed = self.declare_parameter("seed", 0).value
        max_steps = self.declare_parameter("max_steps", 32).value
        # Comma-separated description files, or stress:fresh (the fresh held-out part's own words).
        texts = self.declare_parameter("texts", "").value
        pools = None
        if texts:
            from lwm_models.text.stress import description_pools

            pools = description_pools(texts.split(","))
        self.session = GameSession(split, index, pools, max_steps)
        self.publish_state = self.json_publisher("env/state", "state", LATCHED)
        self.publish_manual = self.json_publisher("env/manual", "manual", LATCHED)
        self.json_service("env/reset", self.on_reset)
        self.json_service("env/step", self.on_step)
        self._announce(self.session.reset(seed))
        self.get_logger().info(f"serving {split}[{index}]: {self.session.env.spec}")

    def health(self) -> tuple[str, dict[str, object]]:
        state = self.session.state()
        where = f"{state['episode_id']} at step {state['t']}" + (" (over)" if state.get("done") else "")
        return f"playing {where}", {"episode": state["episode_id"], "step": state["t"]}

    def _announce(self, state: dict) -> None:
        self.publish_state(state)
        self.publish_manual(self.session.manual())

    def _serve(self, where: str, kind: str, request: str, act) -> str:
        try:
            payload = messages.decode(kind, request)
            if isinstance(payload, dict):  # typed by hand, a request may leave its version out
                payload = {"version": messages.version(kind), **payload}
            state = act(messages.validate(kind, payload))
            return messages.dump(
                "env_response", {"ok": True, "state": messages.validate("state", {"version": 1, **state})}
            )
        except Exception as exc:
            self.report_error(where, exc, request)
            return messages.dump("env_response", {"ok": False, "error": str(exc)[:2000]})

    def on_reset(self, req, res):
        def act(p):
            if p.get("restart") and any(k in p for k in ("seed", "split", "index")):
                raise LwmError("a restart plays the current episode again: give no seed, split or index with it")
            state = self.session.reset(int(p.get("seed", 0)), p.get("split"), p.get("index"), bool(p.get("restart")))
            self._announce(state)
            return state

        res.response = self._serve(self.resolve_service_name("env/reset"), "env_reset_request", req.request, act)
        return res

    def on_step(self, req, res):
        def act(p):
            state = self.session.step(p["action"])
            self.publish_state(state)
            return state

        res.response = self._serve(self.resolve_service_name("env/step"), "env_step_request", req.request, act)
        return res


def main() -> int:
    return run(EnvNode)


if __name__ == "__main__":
    raise SystemExit(main())

"""Messenger environment node: the real game.

Publishes /env/state after every reset and step and the game's manual on /env/manual (latched);
serves /env/reset and /env/step (lwm_interfaces/srv/Json: JSON in, JSON out; schemas
env_reset_request, env_step_request and env_response). With parameter `episode_file` it writes the
episode it plays there at every reset, and starts from the episode written there (the launcher
gives the run's own file): an environment restarted, or a run continued with --resume, returns to
the episode under review, whose review the planner then resumes, not to the first seed's.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from lwm_models import messages
from lwm_models.data.episode import Episode
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
        path = self.declare_parameter("episode_file", "").value
        self.episode_file = Path(path) if path else None
        self.session = GameSession(split, index, pools, max_steps)
        self.publish_state = self.json_publisher("env/state", "state", LATCHED)
        self.publish_manual = self.json_publisher("env/manual", "manual", LATCHED)
        self.json_service("env/reset", self.on_reset)
        self.json_service("env/step", self.on_step)
        earlier = self._earlier_episode(split, index)
        if earlier is not None:
            self.get_logger().info(f"returns to episode {earlier} (from {self.episode_file})")
        self._announce(self.session.resume(earlier) if earlier is not None else self.session.reset(seed))
        self.get_logger().info(f"serving {split}[{index}]: {self.session.env.spec}")

    def _earlier_episode(self, split: str, index: int) -> Episode | None:
        """The episode this run's environment played last, if it is of this game (another game's
        is an older setup's, not this one's to continue)."""
        if self.episode_file is None or not self.episode_file.is_file():
            return None
        try:
            episode = Episode.parse(json.loads(self.episode_file.read_text())["episode_id"])
        except (OSError, ValueError, KeyError, TypeError, LwmError) as exc:
            self.get_logger().warning(f"{self.episode_file}: no episode to return to ({exc}); starting afresh")
            return None
        return episode if (episode.split, episode.index) == (split, index) else None

    def health(self) -> tuple[str, dict[str, object]]:
        state = self.session.state()
        where = f"{state['episode_id']} at step {state['t']}" + (" (over)" if state.get("done") else "")
        return f"playing {where}", {"episode": state["episode_id"], "step": state["t"]}

    def _announce(self, state: dict) -> None:
        if self.episode_file is not None:  # written whole, then renamed: a kill leaves the old one or the new
            self.episode_file.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.episode_file.with_name(f".{self.episode_file.name}.{os.getpid()}")
            tmp.write_text(json.dumps({"episode_id": state["episode_id"]}) + "\n")
            os.replace(tmp, self.episode_file)
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

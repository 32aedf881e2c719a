"""Live view for Foxglove (`./run_nodes.sh --foxglove PORT`): the system's boards as standard
Foxglove messages, served on a Foxglove WebSocket (the foxglove-sdk package) while the system runs,
and written to an MCAP file beside a recording.

Per agent (a fleet's under its namespace: /agent2/board):
- `board` (foxglove.RawImage, rgb8): the real game, after every reset and step;
- `plan` (foxglove.RawImage): the plan under review, its frames left to right with step, action
  and reward under each;
- `plan_summary` (JSON): review, plan, reason, manual version, imagined return, and its sampled
  futures' death and win shares and mean return (a Plot panel draws them over time);
- `report` (JSON): each execution's report without its frames.
An Image panel draws the boards and a Raw Messages or Plot panel the rest, with no custom code.
Open Foxglove, "Open connection", Foxglove WebSocket, ws://HOST:PORT.
"""

from __future__ import annotations

import numpy as np

from lwm_models.messenger.render import render_png, render_trajectory_png
from lwm_nodes.common import LATCHED, JsonNode, agent_topic, declare_agents, run

CELL_PX = 24


class LiveViewNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("live_view")
        import foxglove
        from foxglove.channels import RawImageChannel

        p = self.declare_parameter
        agents = declare_agents(self)
        host = p("host", "127.0.0.1").value
        port = int(p("port", 8770).value)
        mcap = p("mcap", "").value  # also write what it shows to this MCAP file
        self.cell = int(p("cell_px", CELL_PX).value)
        self.server = foxglove.start_server(name="lwm", host=host, port=port)
        self.mcap = foxglove.open_mcap(mcap, allow_overwrite=True) if mcap else None
        self.images: dict[str, RawImageChannel] = {}
        self.log = foxglove.log
        for agent in agents:
            prefix = f"/{agent}" if agent else ""
            for name in ("board", "plan"):
                self.images[f"{prefix}/{name}"] = RawImageChannel(f"{prefix}/{name}")
            for topic, kind, handle in (
                ("env/state", "state", self.on_state),
                ("planner/plan", "plan", self.on_plan),
                ("planner/report", "execution_report", self.on_report),
            ):
                self.json_subscription(
                    agent_topic(agent, topic), kind, lambda m, pre=prefix, handle=handle: handle(pre, m), LATCHED
                )
        self.shown = 0
        print(f"FOXGLOVE live view at ws://{host}:{self.server.port}", flush=True)

    def _image(self, topic: str, image) -> None:
        from foxglove.messages import RawImage, Timestamp

        pixels = np.asarray(image.convert("RGB"), dtype=np.uint8)
        now = self.get_clock().now().nanoseconds
        stamp = Timestamp(sec=now // 1_000_000_000, nsec=now % 1_000_000_000)
        height, width, _ = pixels.shape
        message = RawImage(
            timestamp=stamp, frame_id="board", width=width, height=height, encoding="rgb8", step=width * 3,
            data=pixels.tobytes(),
        )  # fmt: skip
        self.images[topic].log(message, log_time=now)
        self.shown += 1

    def on_state(self, prefix: str, state: dict) -> None:
        self._image(f"{prefix}/board", render_png(np.asarray(state["observation"]), cell=self.cell))

    def on_plan(self, prefix: str, plan: dict) -> None:
        sheet = render_trajectory_png(
            np.asarray(plan["observations"]), None, plan["rewards"], plan["actions"], cell=self.cell, per_row=11
        )
        self._image(f"{prefix}/plan", sheet)
        futures = plan["futures"]
        self.log(
            f"{prefix}/plan_summary",
            {
                "review_id": plan["review_id"],
                "plan_id": plan["plan_id"],
                "reason": plan.get("reason", ""),
                "manual_version": plan["manual_version"],
                "imagined_return": plan["imagined_return"],
                "death_share": futures["death_share"],
                "win_share": futures.get("win_share", 0.0),
                "futures_mean_return": futures["return_mean"],
            },
        )

    def on_report(self, prefix: str, report: dict) -> None:
        frames = ("observations", "planned_observations", "actions")
        self.log(f"{prefix}/report", {k: v for k, v in report.items() if k not in frames})

    def health(self) -> tuple[str, dict[str, object]]:
        return f"serving Foxglove on port {self.server.port}", {"images shown": self.shown}

    def close(self) -> None:
        if self.mcap is not None:
            self.mcap.close()
        self.server.stop()


def main() -> int:
    return run(LiveViewNode)


if __name__ == "__main__":
    raise SystemExit(main())

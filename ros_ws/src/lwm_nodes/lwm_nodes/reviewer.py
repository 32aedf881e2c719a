"""What the human-feedback node (lwm_nodes/human_node.py) tells its reviewer: the terminal, the
page or the scripted reviewer, one module each."""

from __future__ import annotations

import time

from lwm_models.agent.review_text import plan_text


class Reviewer:
    """What a reviewer (terminal, page, scripted) is told; each method is called with the node's
    state already updated. The default does nothing."""

    default_name = "terminal"  # who signs until told otherwise (the page: nobody, until the person says)
    # A label request is taken off the executor when the reviewer calls a service to take it (the
    # page asks the planner whether it is still open, and that answer is delivered by the executor).
    label_requests_off_executor = False
    shows_status = False  # whether it is told the world-model server's status (/lwm/status)

    def start(self) -> None:
        """The node is ready: the reviewer may start reading its input."""

    def on_game(self, game, split: str) -> None:
        """The environment plays another game."""

    def on_plan(self, plan: dict) -> None:
        """A new plan to review."""

    def on_progress(self, progress: dict) -> None:
        """A round of learning before the plan (round 0: what the world model read of the manual)."""

    def take_label_request(self, request: dict) -> float | None:
        """When the planner issued this label request (wall time), or None if it is over: the node
        then does not open it."""
        return time.time()

    def on_label_request(self, request: dict, expires: float | None) -> None:
        """A label request, opened; `expires` is when the planner stops waiting for it (wall time)."""

    def on_labels_sent(self) -> None:
        """The open label request was answered."""

    def on_report(self, report: dict) -> None:
        """An execution's report (the node has printed its summary)."""

    def on_ack(self, ack: dict, sent: dict) -> None:
        """The receiving node's answer to `sent`, something this reviewer sent."""

    def on_status(self, status: dict) -> None:
        """The world-model server's status (when `shows_status`)."""

    def on_notice(self, text: str) -> None:
        """Something the person should know that is no answer to them (a node died and came back)."""
        print(f"NOTICE {text}", flush=True)

    def close(self) -> None:
        """The node shuts down."""


def show(plan: dict, quiet: bool = False, frames: str = "ends") -> None:
    print("\n" + plan_text(plan, "none" if quiet else frames), flush=True)

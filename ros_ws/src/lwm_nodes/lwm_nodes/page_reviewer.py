"""The review on a web page (`./run_nodes.sh --page PORT`, parameters page_port and page_host,
default localhost): the plan and its futures drawn, the manual's legend and what the world model
read of it, the answers, the label requests' states to label, the execution report, and the review
history, which the planner (the ledger's one owner) answers on /planner/history, wherever it runs.
lwm_nodes/review_page.py serves the page; this module turns what the person does there into the
node's messages. Page answers take the terminal's checks, signature and schema, and each waits for
the receiving node's answer, which the page shows beside the control: taken, or refused with the
reason. Nobody answers until the person says who they are (unless the launcher named them with
parameter `reviewer`): their answers are then signed with their own key.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from lwm_models import messages
from lwm_models.agent.imaginer import Unavailable
from lwm_models.agent.review_view import (
    answered_manual,
    history_view,
    label_request_view,
    plan_view,
    progress_view,
    report_view,
)
from lwm_models.errors import LwmError
from lwm_nodes.review_page import ReviewPage, reply
from lwm_nodes.reviewer import Reviewer, show

if TYPE_CHECKING:
    from lwm_nodes.human_node import HumanNode

PAGE_ANSWER_WAIT_S = 8.0  # how long the page's request waits for the receiving node's answer


class PageReviewer(Reviewer):
    default_name = ""  # nobody, until the person says who they are
    label_requests_off_executor = True  # it asks the planner's history whether a request is still open
    shows_status = True  # the manual's version and what the world model read of it

    def __init__(self, node: HumanNode) -> None:
        self.node = node
        self.page = ReviewPage(
            node.declare_parameter("page_host", "127.0.0.1").value,
            int(node.get_parameter("page_port").value),
            on_feedback=self.on_feedback,
            on_manual=self.on_manual,
            on_labels=self.on_labels,
            history=self.history,
            on_episode=self.on_episode,
            on_reviewer=self.on_reviewer,
            on_answer=self.on_answer,
            reviewer=node.signer.reviewer,
        )

    def start(self) -> None:
        print(f"PAGE review page at {self.page.url}", flush=True)

    def close(self) -> None:
        self.page.close()

    # ------------------------------------------------------------------ what the page is shown
    def on_plan(self, plan: dict) -> None:
        self.page.push("plan", plan_view(plan))
        show(plan, quiet=True)  # one line in the node's log; the page draws it

    def on_progress(self, progress: dict) -> None:
        self.page.push("progress", progress_view(progress))

    def on_status(self, status: dict) -> None:
        self.page.push("status", status)

    def on_notice(self, text: str) -> None:
        super().on_notice(text)
        self.page.push("notice", {"text": text, "time": time.time()})

    def on_report(self, report: dict) -> None:
        self.page.push("report", report_view(report))

    def on_label_request(self, request: dict, expires: float | None) -> None:
        # The page counts down to the deadline in wall time (the browser's clock is this host's).
        self.page.push("label_request", {**label_request_view(request), "expires_at": expires})

    def on_labels_sent(self) -> None:
        self.page.push("label_request", None)

    def take_label_request(self, request: dict) -> float | None:
        """When the planner issued this label request (wall time), or None when it waits for it no
        more, from the planner's history (/planner/history). The request is latched: a restarted
        node gets the last one however old, perhaps answered, and the page would ask the person to
        label it again for nothing. Over: the history holds its labels, a later request, a plan or
        a report after it, or its deadline has passed (the planner may not have written what it did
        next yet). Without an answer from the planner, or one that does not hold this request, the
        request is taken as new: a request wrongly dropped would end the person's round."""
        try:
            history = self.node.history(request["review_id"])["records"]
        except (Unavailable, LwmError, KeyError):
            return time.time()
        issued = {
            "request_id": request["request_id"],
            "round": request["round"],
            "states": len(request["observations"]),
        }
        for i, rec in enumerate(history):
            if rec["kind"] == "label_request" and all(rec["payload"].get(k) == v for k, v in issued.items()):
                ends = ("labels", "label_request", "plan", "report")
                moved_on = any(later["kind"] in ends for later in history[i + 1 :])
                expired = rec["time"] + request.get("timeout", float("inf")) <= time.time()
                return None if moved_on or expired else rec["time"]
        return time.time()

    # ------------------------------------------------------------------ what the person does there
    def _answer(self, msg_id: str, who: str) -> str:
        return reply(self.node.answer_to(msg_id, PAGE_ANSWER_WAIT_S), who, PAGE_ANSWER_WAIT_S)

    def on_feedback(self, body: dict) -> str:
        """An answer to the plan; the schema (checked before publishing) refuses a wrong one, the
        planner the rest. Returns the planner's words; raises with them when it refuses."""
        if body.get("decision") == "undo":  # a manual or learning, whichever is newest
            msg_id, who, what = self.node.undo()
            self.node.get_logger().info(f"page: taking back {what}")
            return self._answer(msg_id, who)
        allowed = ("review_id", "plan_id", "decision", "corrections", "rounds")
        msg_id = self.node.publish_feedback({k: v for k, v in body.items() if k in allowed})
        self.node.get_logger().info(f"page: {body.get('decision')} on plan {body.get('plan_id')}")
        said = self._answer(msg_id, "the planner")
        if body.get("decision") == "stop":  # the planner waits for no more labels: nothing to label
            self.node.close_label_request()
            self.page.push("label_request", None)
        return said

    def on_labels(self, body: dict) -> str:
        """Labels: the schema first (a page's payload is as untrusted as a topic's), then the
        node's checks against the open request."""
        fields = {k: body.get(k) for k in ("review_id", "request_id", "states", "actions")}
        labels = messages.validate("labels", {"version": messages.version("labels"), **fields})
        request = self.node.request
        if request is not None and labels["review_id"] != request["review_id"]:
            raise ValueError(f"these labels are for review {labels['review_id']!r}, not {request['review_id']!r}")
        msg_id = self.node.send_labels(labels["states"], labels["actions"], labels["request_id"])
        self.node.get_logger().info(f"page: {len(labels['states'])} label(s) for request {labels['request_id']}")
        return self._answer(msg_id, "the planner")

    def on_answer(self, body: dict) -> str:
        """An answer to the plan's question about the manual: the manual again, with the fact."""
        manual = answered_manual(self.node.plan, [str(body.get("choice", ""))])
        msg_id = self.node.publish_manual(manual)
        self.node.get_logger().info(f"page: answered {manual['facts'][-1]}")
        return self._answer(msg_id, "the world-model server")

    def on_manual(self, body: dict) -> str:
        msg_id = self.node.publish_manual({"descriptions": body["descriptions"], "source": "human"})
        self.node.get_logger().info("page: a new manual")
        return self._answer(msg_id, "the world-model server")

    def on_episode(self, body: dict) -> str:
        return self.node.next_episode(body.get("seed"), bool(body.get("restart", False)))

    def on_reviewer(self, body: dict) -> str:
        """The person says who they are: their answers are signed with their own key."""
        who = self.page.become(body, self.node.signer)
        self.node.get_logger().info(f"page: the reviewer is now {who!r}")
        return f"you answer as {who}: your answers are signed with your own key"

    def history(self, review_id: str | None) -> dict:
        """The reviews the planner keeps, or one review's records, as the page lists them."""
        try:
            found = self.node.history(review_id)
        except (Unavailable, LwmError) as exc:  # the planner is not up yet, or cannot read its ledger now
            return {"reviews": [], "records": [], "note": f"no history from the planner: {exc}"}
        if review_id is None:
            return {"ledger": found["ledger"], "reviews": found["reviews"]}
        return {"ledger": found["ledger"], "review_id": review_id, "records": history_view(found["records"])}

"""Human-feedback node: the person's side of the review.

It shows each plan to a reviewer and publishes what they answer: a decision on the plan
(review/feedback), labels for the planner's label requests (review/labels) and new manuals
(feedback/manual, or parameter `manual_topic`), each signed as the reviewer (lwm_nodes.trust) and each answered by the
receiving node on /lwm/acks, an answer that comes back to the reviewer (taken, or refused with the
reason). It also starts the next episode, or this one again, on the reviewer's word (env/reset).
Names are relative: in an agent's namespace the node reviews that agent.

The reviewer is one of three, chosen by parameter; each is a module of its own:
- the terminal (default): lwm_nodes/terminal_reviewer.py, commands typed on stdin;
- the page (page_port:=PORT, `./run_nodes.sh --page PORT`): lwm_nodes/page_reviewer.py, the review
  page in the browser (lwm_nodes/review_page.py serves it);
- the scripted reviewer (scripted:=true): lwm_nodes/scripted_reviewer.py, the paper's simulated
  human, which reviews a number of episodes and exits.
This module holds what they share: what is under review now (the episode, the plan, the open label
request, the execution), the checks on labels, and the messages in and out.
"""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable

from lwm_interfaces.srv import Json

from lwm_models import messages
from lwm_models.agent.imaginer import ServiceImaginer
from lwm_models.agent.review import check_labels
from lwm_models.agent.undo import last_change, manual_before
from lwm_models.data.episode import Episode
from lwm_models.data.splits import load_split
from lwm_models.errors import LwmError
from lwm_nodes.common import DIAGNOSTICS_TOPIC, EVENTS, FEEDBACK, LATCHED, Answers, JsonNode, json_caller, run
from lwm_nodes.reviewer import Reviewer
from lwm_nodes.trust import Signer

HISTORY_WAIT_S = 5.0  # how long a history request waits for the planner's /planner/history


# How a person hears of the other nodes (by node name).
RESUME_S = 3.0  # how long a restarted node is given to resume before the person hears what it does
NODE_NAMES = {"lwm_world_model": "world-model server", "planner": "planner", "messenger_env": "environment"}


class HumanNode(JsonNode):
    def __init__(self, stop: threading.Event) -> None:
        super().__init__("human_feedback")
        p = self.declare_parameter
        scripted = bool(p("scripted", False).value)
        port = int(p("page_port", 0).value)
        self.quiet = bool(p("quiet", False).value)  # one line per plan instead of its frames
        self.stop = stop
        self.game = None
        self.split = ""
        self.episode: str | None = None  # the episode the environment plays now
        self.plan: dict | None = None
        self.request: dict | None = None
        self.request_deadline = float("inf")  # monotonic; when the planner stops waiting for its labels
        self.answered: set[tuple[str, int]] = set()  # (review_id, request_id): the planner takes one answer
        self.labels_lock = threading.Lock()  # the page answers from its own threads (a double click, too)
        self.executing: str | None = None  # the review whose approved plan the agent plays now
        self.reported: set[str] = set()  # reviews whose report came (an ack may come after it)
        # What this node sent, until the receiving node answers on /lwm/acks.
        self.answers = Answers(self, self.on_answer)
        # Service calls (imagination, resets, history) wait for answers the executor delivers: a
        # reviewer's work that calls them runs in this thread, never in a callback.
        self.work: queue.Queue = queue.Queue()
        threading.Thread(target=self._work, daemon=True).start()

        if scripted:
            from lwm_nodes.scripted_reviewer import SimulatedReviewer as chosen
        elif port:
            from lwm_nodes.page_reviewer import PageReviewer as chosen
        else:
            from lwm_nodes.terminal_reviewer import TerminalReviewer as chosen
        self.signer = Signer(self, chosen.default_name)
        self.reviewer: Reviewer = chosen(self)

        def sender(topic: str, schema: str, qos) -> Callable[[dict], str]:
            return self.answers.sender(self.signer.publisher(self.json_publisher(topic, schema, qos), schema))

        self.publish_feedback = sender("review/feedback", "review_feedback", FEEDBACK)
        self.publish_labels = sender("review/labels", "labels", FEEDBACK)
        # feedback/manual in this node's namespace: its agent's manual (the single agent's, or in a
        # fleet, one agent's); the launcher points a fleet's reviewer at /feedback/manual, every agent's.
        manual_topic = p("manual_topic", "feedback/manual").value
        self.publish_manual = sender(manual_topic, "manual", LATCHED)
        self.imaginer = ServiceImaginer(
            json_caller(self, self.create_client(Json, "lwm/imagine"), "imagine_response", 30.0)
        )
        self.env_reset = json_caller(self, self.create_client(Json, "env/reset"), "env_response", 30.0)
        self.history_call = json_caller(
            self, self.create_client(Json, "planner/history"), "history_response", HISTORY_WAIT_S
        )
        self.json_subscription("env/state", "state", self.on_state, LATCHED)
        self.json_subscription("planner/plan", "plan", self.on_plan, LATCHED)
        self.json_subscription("planner/label_request", "label_request", self.on_label_request, LATCHED)
        self.json_subscription("planner/report", "execution_report", self.on_report, LATCHED)
        self.json_subscription("planner/progress", "progress", self.reviewer.on_progress, LATCHED)
        if self.reviewer.shows_status:
            self.json_subscription("lwm/status", "status", self.reviewer.on_status, LATCHED)
        self.started_at: dict[str, str] = {}  # node -> when it said it started (/diagnostics)
        self.came_back: dict[str, float] = {}  # node -> when this node saw it start again (monotonic)
        from diagnostic_msgs.msg import DiagnosticArray

        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self.on_diagnostics, EVENTS)
        self.reviewer.start()

    def on_diagnostics(self, array) -> None:
        """A node whose start time changed died and came back: the person hears it, and what the
        node says it does now (its health line, once it has had RESUME_S to resume its work), since
        what they see may have changed with it."""
        for status in array.status:
            started = next((kv.value for kv in status.values if kv.key == "started"), None)
            if started is None or status.name == self.get_fully_qualified_name():
                continue
            before = self.started_at.get(status.name)
            self.started_at[status.name] = started
            if before is not None and before != started:
                self.came_back[status.name] = time.monotonic()
            seen = self.came_back.get(status.name)
            if seen is not None and time.monotonic() - seen >= RESUME_S:
                del self.came_back[status.name]
                who = NODE_NAMES.get(status.name.rsplit("/", 1)[-1], status.name)
                self.reviewer.on_notice(f"the {who} stopped and started again; it says: {status.message}")

    # ------------------------------------------------------------------ what this node sends
    def on_answer(self, ack: dict, sent: dict) -> None:
        """The receiving node's answer to something this node sent."""
        if ack["ok"] and sent.get("decision") == "approve" and sent["review_id"] not in self.reported:
            self.executing = sent["review_id"]  # the planner plays it now: no reset under its feet
        self.reviewer.on_ack(ack, sent)

    def answer_to(self, msg_id: str, timeout: float) -> dict | None:
        """The receiving node's answer to msg_id, waiting up to `timeout` seconds; None if none came."""
        return self.answers.wait(msg_id, timeout)

    def next_episode(self, seed: int | None = None, restart: bool = False) -> str:
        """Start the next episode of this game (the next seed, or `seed`), or with `restart` this
        episode again from its start: the environment resets and the planner opens a fresh review.
        The one place a reviewer resets the game (the planner resets it only to replay the episode
        it executes). Raises ValueError with the reason when it cannot."""
        if self.episode is None and (restart or seed is None):
            raise ValueError("no episode yet: the environment has not said which game it plays")
        if self.executing is not None:
            raise ValueError(
                f"the agent is playing the approved plan of review {self.executing} in the game: "
                "wait for its report, or stop it first"
            )
        if restart:
            if seed is not None:
                raise ValueError("a restart plays this episode again: it takes no seed")
            request = {"restart": True}
        else:
            seed = Episode.parse(self.episode).seed + 1 if seed is None else seed
            if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
                raise ValueError(f"a seed is a whole number >= 0, not {seed!r}")
            request = {"seed": seed}
        answer = self.env_reset(request)
        if not answer.get("ok"):
            raise ValueError(f"the environment refused: {answer.get('error', 'no reason given')}")
        episode = answer["state"]["episode_id"]
        again = " again (a new review of the same board)" if restart else ""
        return f"episode {episode} started{again}; its plan follows"

    def undo(self) -> tuple[str, str, str]:
        """Take back the person's newest change still in force in the review under way (lwm_models/
        agent/undo.py): a manual by sending the one before it again, learning by feedback `undo`
        (the planner returns to the policy it had before). Returns (msg_id, who answers, what is
        taken back); raises with the reason when there is nothing to take back."""
        plan = self.plan
        if plan is None:
            raise ValueError("there is no plan under review yet: nothing to take back")
        change = last_change(self.history(plan["review_id"])["records"])
        if change.kind == "manual":
            return self.publish_manual(manual_before(change)), "the world-model server", change.words()
        feedback = {"review_id": plan["review_id"], "plan_id": plan["plan_id"], "decision": "undo"}
        return self.publish_feedback(feedback), "the planner", change.words()

    def send_labels(self, states: list[int], actions: list[int], request_id: int | None = None) -> str:
        """Labels from the reviewer for the open label request; request_id, when given, is the
        request they looked at. Refused with the reason, nothing published, when they do not fit
        it: labels for another request would teach the wrong states. Returns the msg_id."""
        with self.labels_lock:
            request = self.request
            if request is None:
                raise ValueError("there is no label request")
            if request_id is not None and request_id != request["request_id"]:
                raise ValueError(
                    f"these labels are for request {request_id}, but the request is {request['request_id']}"
                )
            key = (request["review_id"], request["request_id"])
            if key in self.answered:
                raise ValueError(f"request {request['request_id']} is answered already (the planner takes one answer)")
            if time.monotonic() > self.request_deadline:
                waits = request["timeout"]
                raise ValueError(
                    f"request {request['request_id']} has expired: the planner waits {waits:.0f} s for labels"
                )
            check_labels(request, states, actions)
            ids = {"review_id": request["review_id"], "request_id": request["request_id"]}
            msg_id = self.publish_labels({**ids, "states": states, "actions": actions})
            self.answered.add(key)
        self.reviewer.on_labels_sent()
        return msg_id

    @property
    def label_request_open(self) -> bool:
        """The planner still waits for labels of the request shown (not answered, not expired, not
        stopped), as the planner's own diagnostics say it."""
        request = self.request
        if request is None or time.monotonic() > self.request_deadline:
            return False
        return (request["review_id"], request["request_id"]) not in self.answered

    def close_label_request(self) -> None:
        """The planner waits for no more labels (the reviewer stopped the teaching)."""
        with self.labels_lock:
            self.request = None

    def history(self, review_id: str | None = None) -> dict:
        """The planner's answer on /planner/history: the reviews, or one review's records. Raises
        Unavailable when the planner does not answer, LwmError when it cannot read its ledger."""
        asked = {"version": messages.version("history_request")}
        answer = self.history_call(asked if review_id is None else {**asked, "review_id": review_id})
        if not answer["ok"]:
            raise LwmError(answer["error"])
        return answer

    def health(self) -> tuple[str, dict[str, object]]:
        waiting, lost = self.answers.awaited()
        plan = self.plan
        values = {
            "reviewer": self.signer.reviewer or "nobody yet",
            "episode": self.episode or "none yet",
            "label request open": self.label_request_open,
            "answers awaited": waiting,
            "answers that never came": lost,
        }
        if plan is None:
            return "waiting for a plan", values
        values["plan"] = f"{plan['review_id']} plan {plan['plan_id']}"
        doing = f"the agent plays review {self.executing}" if self.executing else f"plan {plan['plan_id']} shown"
        return doing, values

    # ------------------------------------------------------------------ what this node hears
    def on_state(self, payload: dict) -> None:
        self.episode = payload["episode_id"]
        g = payload["game"]
        game = load_split(g["split"])[g["index"]]
        if game is not self.game:
            self.game, self.split = game, g["split"]
            self.reviewer.on_game(game, g["split"])

    def on_plan(self, plan: dict) -> None:
        if (
            self.plan is not None
            and plan["review_id"] == self.plan["review_id"]
            and plan["plan_id"] <= self.plan["plan_id"]
        ):
            return  # a latched repeat
        self.plan = plan
        if plan["reason"] == "divergence" and self.executing == plan["review_id"]:
            self.executing = None  # the execution waits for this plan's review
        self.reviewer.on_plan(plan)

    def on_label_request(self, request: dict) -> None:
        if self.reviewer.label_requests_off_executor:
            self.work.put(lambda: self._open_label_request(request))
        else:
            self._open_label_request(request)

    def _open_label_request(self, request: dict) -> None:
        if (
            self.request is not None
            and request["review_id"] == self.request["review_id"]
            and request["request_id"] <= self.request["request_id"]
        ):
            return
        issued = self.reviewer.take_label_request(request)
        if issued is None:
            self.get_logger().info(
                f"label request {request['request_id']} is over (in the planner's history, or expired); not shown"
            )
            return
        waits = request.get("timeout", float("inf"))
        with self.labels_lock:
            self.request = request
            self.request_deadline = time.monotonic() + (issued + waits - time.time())
        self.reviewer.on_label_request(request, issued + waits if "timeout" in request else None)

    def on_report(self, report: dict) -> None:
        self.reported.add(report["review_id"])
        if self.executing == report["review_id"]:
            self.executing = None
        print(
            f"SUMMARY review {report['review_id']}: plan {report['plan_id']} after {report['revisions']} revision(s); "
            f"imagined return {report['imagined_return']:+.2f}, real return {report['real_return']:+.2f}, "
            f"{report['steps']} steps, {report['outcome']}, reviews asked again {report.get('reviews_asked', 0)}",
            flush=True,
        )
        self.reviewer.on_report(report)

    def _work(self) -> None:
        while True:
            job = self.work.get()
            try:
                job()
            except Exception as exc:  # a failed answer must not end the review
                self.report_error("reviewer", exc)

    def close(self) -> None:
        self.reviewer.close()


def main() -> int:
    stop = threading.Event()
    return run(lambda: HumanNode(stop), stop)


if __name__ == "__main__":
    raise SystemExit(main())

"""Human-feedback node: shows each plan to a person and publishes what they answer.

Interactive (a terminal): the plan's imagined frames (ASCII), rewards, confidence and sampled
futures, then
    a                 approve (the planner's policy then acts in the real game)
    r                 reject (the planner imagines again)
    c STEP:ACTION ... corrections, e.g. "c 1:3 2:3" (actions 0 up, 1 down, 2 left, 3 right, 4 stay)
    i [ROUNDS]        teach: rounds of learning in imagination, each asking you to label a few
                      imagined states (where the agent is unsure what the manual means)
    stop              end the teaching under way (the agent keeps what it learnt, re-plans),
                      or the execution of an approved plan (no further move; a report follows)
    l STATE:ACTION ...  label states of the current label request ("l -" sends none); one answer
                      per request, before the planner stops waiting (the request's timeout)
    x                 abort: execute nothing
    m                 a new manual, three descriptions, one per line (published on /feedback/manual)
    n [SEED]          the next episode of this game (the next seed, or SEED): a fresh review
    restart           this episode again from its start (same board and seed), as a fresh review
    f                 every frame of the plan (a plan shows its start and last board, a line per step)
    s N               state N of the label request, beside the state a step before it
Every answer, label batch and manual gets the receiving node's answer on /lwm/acks (printed here,
shown on the page): taken, or refused with the reason.
Scripted (parameter scripted:=true): the paper's simulated human, the expert reading the true
manual (lwm_models.agent.reviewer): it labels every state a teaching round asks about, corrects,
and never approves a plan whose shown trajectory dies; it prints a summary when the execution
report arrives and exits. With language:=true its first answer in each review is language
feedback: the true manual in other words, published on /feedback/manual (texts:= the description
files to draw them from; default: the project's generator).
With page_port:=PORT (`./run_nodes.sh --page PORT`) it serves the review page in the browser
instead of reading the terminal (lwm_nodes/review_page.py, on page_host, default localhost): the
plan and its futures drawn, the manual's legend, the answers, the label requests' states to label,
the execution report, and the review history, which the planner (the ledger's one owner) answers on
/planner/history, wherever it runs. Page answers take the
terminal's code paths: the same checks, signature and schema.
Everything it publishes is signed as reviewer `reviewer` (default: scripted or terminal; on the page,
nobody until the person says who they are) with that reviewer's key from `keys_file`
(lwm_nodes.trust); the planner and the simulator take nothing else.
"""

from __future__ import annotations

import queue
import sys
import threading
import time
import uuid
from collections.abc import Callable

from lwm_interfaces.srv import Json
from std_msgs.msg import String

from lwm_models import messages
from lwm_models.agent.imaginer import ServiceImaginer, Unavailable
from lwm_models.agent.review import check_labels
from lwm_models.agent.review_text import plan_text, progress_text, state_text
from lwm_models.agent.review_view import history_view, label_request_view, plan_view, progress_view, report_view
from lwm_models.agent.reviewer import ScriptedReviewer
from lwm_models.data.episode import Episode
from lwm_models.data.splits import load_split
from lwm_models.errors import LwmError
from lwm_nodes.common import ACKS, ACKS_TOPIC, FEEDBACK, LATCHED, JsonNode, json_caller, run
from lwm_nodes.review_page import ReviewPage
from lwm_nodes.trust import Signer

PAGE_ANSWER_WAIT_S = 8.0  # how long the page's request waits for the receiving node's answer
HISTORY_WAIT_S = 5.0  # how long the page's history waits for the planner's /planner/history


class Refused(ValueError):
    """The receiving node refused what the person sent; the message is its reason."""


class NoAnswer(ValueError):
    """Nothing answered what the person sent in time (it may still be taken)."""


class HumanNode(JsonNode):
    def __init__(self, stop: threading.Event) -> None:
        super().__init__("human_feedback")
        p = self.declare_parameter
        self.scripted = bool(p("scripted", False).value)
        self.teach = p("teach", "online_il").value
        self.approve_return = float(p("approve_return", 1.0).value)
        self.max_death_share = float(p("max_death_share", 0.5).value)
        self.episodes = int(p("episodes", 1).value)  # scripted: reviews before it exits
        self.reports: set[str] = set()
        self.max_rounds = int(p("max_rounds", 4).value)
        self.quiet = bool(p("quiet", False).value)  # scripted: one line per plan instead of frames
        self.language = bool(p("language", False).value)  # scripted: a reworded manual first
        self.texts = p("texts", "").value  # comma-separated description files for the rewording
        self.pools = None
        self.split = ""
        self.stop = stop
        self.game = None
        self.episode: str | None = None  # the episode the environment plays now
        self.reviewer: ScriptedReviewer | None = None
        self.plan: dict | None = None
        self.request: dict | None = None
        self.request_deadline = float("inf")  # monotonic; when the planner stops waiting for its labels
        self.answered: set[tuple[str, int]] = set()  # (review_id, request_id): the planner takes one answer
        self.labels_lock = threading.Lock()  # the page answers from its own threads (a double click, too)
        port = int(p("page_port", 0).value)
        # At the page nobody answers until the person says who they are (unless the launcher said).
        signer = Signer(self, "scripted" if self.scripted else "" if port else "terminal")
        self.signer = signer
        self.executing: str | None = None  # the review whose approved plan the agent plays now
        self.reported: set[str] = set()  # reviews whose report came (an ack may come after it)
        # What this node sent, by msg_id, until the receiving node answers on /lwm/acks.
        self.sent: dict[str, dict] = {}
        self.sent_lock = threading.Lock()
        self.publish_feedback = self._answered(
            signer.publisher(self.json_publisher("/review/feedback", "review_feedback", FEEDBACK), "review_feedback")
        )
        self.publish_labels = self._answered(
            signer.publisher(self.json_publisher("/review/labels", "labels", FEEDBACK), "labels")
        )
        self.publish_manual = self._answered(
            signer.publisher(self.json_publisher("/feedback/manual", "manual", LATCHED), "manual")
        )
        self.create_subscription(String, ACKS_TOPIC, self.on_ack, ACKS)
        self.imaginer = ServiceImaginer(
            json_caller(self, self.create_client(Json, "/lwm/imagine"), "imagine_response", 30.0)
        )
        self.env_reset = json_caller(self, self.create_client(Json, "/env/reset"), "env_response", 30.0)
        self.history_call = json_caller(
            self, self.create_client(Json, "/planner/history"), "history_response", HISTORY_WAIT_S
        )
        self.json_subscription("/env/state", "state", self.on_state, LATCHED)
        self.json_subscription("/planner/plan", "plan", self.on_plan, LATCHED)
        self.json_subscription("/planner/label_request", "label_request", self.on_label_request, LATCHED)
        self.json_subscription("/planner/report", "execution_report", self.on_report, LATCHED)
        self.json_subscription("/planner/progress", "progress", self.on_progress, LATCHED)
        self.page = None
        if port and not self.scripted:
            self.page = ReviewPage(
                p("page_host", "127.0.0.1").value,
                port,
                on_feedback=self.on_page_feedback,
                on_manual=self.on_page_manual,
                on_labels=self.on_page_labels,
                history=self.page_history,
                on_episode=self.on_page_episode,
                on_reviewer=self.on_page_reviewer,
                reviewer=signer.reviewer,
            )
            self.json_subscription("/lwm/status", "status", lambda s: self.page.push("status", s), LATCHED)
            print(f"PAGE review page at {self.page.url}", flush=True)
        # The scripted reviewer may imagine through /lwm/imagine (filtered BC), which must not block
        # the executor that delivers the answer: it works in its own thread.
        self.work: queue.Queue = queue.Queue()
        threading.Thread(target=self._work, daemon=True).start()
        if not self.scripted and self.page is None:
            threading.Thread(target=self.read_commands, daemon=True).start()

    def _answered(self, publish: Callable[[dict], None]) -> Callable[[dict], str]:
        """`publish`, with a msg_id on each payload, so that the receiving node's answer on
        /lwm/acks comes back to this sender; returns the msg_id."""

        def send(payload: dict) -> str:
            msg_id = f"{self.get_name()}-{uuid.uuid4().hex[:12]}"
            with self.sent_lock:
                self.sent[msg_id] = {"event": threading.Event(), "ack": None, "payload": payload}
            publish({**payload, "msg_id": msg_id})
            return msg_id

        return send

    def on_ack(self, msg: String) -> None:
        """The receiving node's answer to something this node sent: the terminal prints it, the
        page's waiting request gets it. Answers to others, and repeats, are ignored."""
        try:
            ack = messages.parse("ack", msg.data)
        except messages.MessageError as exc:
            self.report_error(ACKS_TOPIC, exc, msg.data)
            return
        with self.sent_lock:
            entry = self.sent.get(ack["msg_id"] or "")
            if entry is None or entry["ack"] is not None:
                return
            entry["ack"] = ack
        sent = entry["payload"]
        if ack["ok"] and sent.get("decision") == "approve" and sent["review_id"] not in self.reported:
            self.executing = sent["review_id"]  # the planner plays it now: no reset under its feet
        entry["event"].set()
        if self.page is None:
            who = ack["node"].replace("lwm_", "")
            print(f"{who}: {ack['reason']}" if ack["ok"] else f"REFUSED by the {who}: {ack['reason']}", flush=True)

    def answer_to(self, msg_id: str, timeout: float = PAGE_ANSWER_WAIT_S) -> dict | None:
        """The receiving node's answer to msg_id, waiting up to `timeout` seconds; None if none came."""
        with self.sent_lock:
            entry = self.sent.get(msg_id)
        if entry is None or not entry["event"].wait(timeout):
            return None
        return entry["ack"]

    def next_episode(self, seed: int | None = None, restart: bool = False) -> str:
        """Start the next episode of this game (the next seed, or `seed`), or with `restart` this
        episode again from its start: the environment resets and the planner opens a fresh review."""
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

    def on_page_episode(self, body: dict) -> str:
        return self.next_episode(body.get("seed"), bool(body.get("restart", False)))

    def on_page_reviewer(self, body: dict) -> str:
        """The person at the page says who they are: their answers are signed with their own key."""
        name = body.get("reviewer")
        if not isinstance(name, str) or not name.strip():
            raise ValueError("type your name: 1-64 letters, digits, '_', '.' or '-'")
        who = self.signer.become(name.strip())
        self.get_logger().info(f"page: the reviewer is now {who!r}")
        self.page.set_reviewer(who)
        return f"you answer as {who}: your answers are signed with your own key"

    def on_state(self, payload: dict) -> None:
        self.episode = payload["episode_id"]
        g = payload["game"]
        game = load_split(g["split"])[g["index"]]
        if game is not self.game:
            self.game, self.split = game, g["split"]
            self.reviewer = ScriptedReviewer(
                game, self.teach, self.approve_return, self.max_death_share, self.max_rounds, language=self.language
            )

    def on_progress(self, progress: dict) -> None:
        """The agent learns from a manual before its plan: the page shows each round; the terminal
        says what the world model read (round 0, roles and movements) and when it ends (a line a
        round would bury the plan)."""
        if self.page is not None:
            self.page.push("progress", progress_view(progress))
        elif not self.scripted and ((progress["round"] == 0 and progress.get("roles")) or progress["done"]):
            print(progress_text(progress), flush=True)

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
        if self.page is not None:
            self.page.push("plan", plan_view(plan))
            show(plan, quiet=True)
            return
        show(plan, self.quiet)
        if self.scripted:
            self.work.put(lambda: self.answer_scripted(plan))
        else:
            print(
                "answer: a approve | r reject | c STEP:ACTION ... correct | i [ROUNDS] teach | x abort | m manual | "
                "n next episode | restart this episode | f every frame | stop (teaching or the agent's play)",
                flush=True,
            )

    def answer_scripted(self, plan: dict) -> None:
        if self.reviewer is None:
            print("scripted human: no game state yet; cannot review", flush=True)
            return
        if self.reviewer.wants_to_speak(plan):
            self.speak(plan)
            return
        feedback = self.reviewer.review(plan, self.imaginer)
        self.publish_feedback(feedback)
        detail = {
            "corrections": lambda: f" {len(feedback['corrections'])} step(s)",
            "demonstrations": lambda: f" {len(feedback['demonstrations'])} plans",
        }
        what = feedback["decision"] + detail.get(feedback["decision"], str)()
        print(f"scripted human: {what} on plan {plan['plan_id']}", flush=True)

    def speak(self, plan: dict) -> None:
        """Language feedback: the planner re-plans under the new manual version, and that plan is
        the one reviewed."""
        if self.pools is None:
            from lwm_models.text import DescriptionPools

            self.pools = (
                DescriptionPools.from_files(self.texts.split(",")) if self.texts else DescriptionPools.generated()
            )
        seed = Episode.parse(plan["review_id"]).seed
        manual = self.reviewer.reworded_manual(self.pools, self.split, plan["manual"], seed)
        self.publish_manual({"descriptions": manual, "source": "human"})
        # The wall time lets benchmarks/review_loop.py time feedback -> revised plan.
        print(f"scripted human: manual feedback on plan {plan['plan_id']} at {time.time():.3f}", flush=True)

    def on_label_request(self, request: dict) -> None:
        if self.page is not None:
            # The page asks the planner whether the request is still open (/planner/history), and a
            # service call waits for an answer the executor must deliver: not on the executor.
            self.work.put(lambda: self._take_label_request(request))
        else:
            self._take_label_request(request)

    def _take_label_request(self, request: dict) -> None:
        if (
            self.request is not None
            and request["review_id"] == self.request["review_id"]
            and request["request_id"] <= self.request["request_id"]
        ):
            return
        issued = time.time()
        if self.page is not None:
            issued = self.request_issued(request)
            if issued is None:
                self.get_logger().info(
                    f"label request {request['request_id']} is over (in the planner's history, or expired); not shown"
                )
                return
        waits = request.get("timeout", float("inf"))
        with self.labels_lock:
            self.request = request
            self.request_deadline = time.monotonic() + (issued + waits - time.time())
        n = len(request["observations"])
        if self.page is not None:
            # The page counts down to the deadline in wall time (the browser's clock is this host's).
            expires = issued + waits if "timeout" in request else None
            self.page.push("label_request", {**label_request_view(request), "expires_at": expires})
        elif self.scripted and self.reviewer is not None:
            self.publish_labels(self.reviewer.label(request))
            if not self.quiet or request["round"] == request["rounds"]:
                print(
                    f"scripted human: labelled {n} states of round {request['round']}/{request['rounds']}", flush=True
                )
        else:
            print(
                f"label request {request['request_id']} (round {request['round']}/{request['rounds']}): the agent "
                f"asks about {n} imagined state(s); label them with l STATE:ACTION ... (states 0..{n - 1}), l - for "
                f"none; s N shows state N; the planner waits {waits:.0f} s; stop ends the teaching",
                flush=True,
            )
            for k in range(n):
                self.show_state(k)

    def request_issued(self, request: dict) -> float | None:
        """When the planner issued this label request (wall time), or None when it waits for it no
        more, from the planner's history (/planner/history). The request is latched: a restarted
        node gets the last one however old, perhaps answered, and the page would ask the person to
        label it again for nothing. Over: the history holds its labels, a later request, a plan or
        a report after it, or its deadline has passed (the planner may not have written what it did
        next yet). Without an answer from the planner, or one that does not hold this request, the
        request is taken as new: a request wrongly dropped would end the person's round."""
        try:
            history = self.history(request["review_id"])["records"]
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

    def show_state(self, k: int) -> None:
        """State k of the label request, beside the state a step before it in its episode."""
        request = self.request
        if request is None:
            raise ValueError("there is no label request")
        if not 0 <= k < len(request["observations"]):
            raise ValueError(f"state {k} is not in the request (states 0..{len(request['observations']) - 1})")
        if request.get("previous") is not None:  # chosen states, each with the board before it
            earlier = request["previous"][k]
        else:
            before = label_request_view(request)["before"][k]
            earlier = request["observations"][before] if before >= 0 else None
        print(state_text(request, k, earlier), flush=True)

    def on_page_feedback(self, body: dict) -> str:
        """An answer from the page; the schema (checked before publishing) refuses a wrong one,
        the planner the rest. Returns the planner's words; raises with them when it refuses."""
        allowed = ("review_id", "plan_id", "decision", "corrections", "rounds")
        msg_id = self.publish_feedback({k: v for k, v in body.items() if k in allowed})
        self.get_logger().info(f"page: {body.get('decision')} on plan {body.get('plan_id')}")
        said = self._page_answer(msg_id, "the planner")
        if body.get("decision") == "stop":  # the planner waits for no more labels: nothing to label
            with self.labels_lock:
                self.request = None
            self.page.push("label_request", None)
        return said

    def _page_answer(self, msg_id: str, who: str) -> str:
        ack = self.answer_to(msg_id)
        if ack is None:
            raise NoAnswer(f"sent, but {who} has not answered in {PAGE_ANSWER_WAIT_S:.0f} s (is it running?)")
        if not ack["ok"]:
            raise Refused(ack["reason"])
        return ack["reason"]

    def send_labels(self, states: list[int], actions: list[int], request_id: int | None = None) -> str:
        """Labels from a person (terminal or page) for the current label request; request_id, when
        given, is the request they looked at. Refused with the reason, nothing published, when
        they do not fit it: labels for another request would teach the wrong states."""
        with self.labels_lock:
            return self._send_labels(states, actions, request_id)

    def _send_labels(self, states: list[int], actions: list[int], request_id: int | None) -> str:
        request = self.request
        if request is None:
            raise ValueError("there is no label request")
        if request_id is not None and request_id != request["request_id"]:
            raise ValueError(f"these labels are for request {request_id}, but the request is {request['request_id']}")
        key = (request["review_id"], request["request_id"])
        if key in self.answered:
            raise ValueError(f"request {request['request_id']} is answered already (the planner takes one answer)")
        if time.monotonic() > self.request_deadline:
            waits = request["timeout"]
            raise ValueError(f"request {request['request_id']} has expired: the planner waits {waits:.0f} s for labels")
        check_labels(request, states, actions)
        ids = {"review_id": request["review_id"], "request_id": request["request_id"]}
        msg_id = self.publish_labels({**ids, "states": states, "actions": actions})
        self.answered.add(key)
        if self.page is not None:
            self.page.push("label_request", None)
        return msg_id

    def on_page_labels(self, body: dict) -> str:
        """Labels from the page: the schema first (a page's payload is as untrusted as a topic's),
        then the terminal's path."""
        fields = {k: body.get(k) for k in ("review_id", "request_id", "states", "actions")}
        labels = messages.validate("labels", {"version": messages.version("labels"), **fields})
        request = self.request
        if request is not None and labels["review_id"] != request["review_id"]:
            raise ValueError(f"these labels are for review {labels['review_id']!r}, not {request['review_id']!r}")
        msg_id = self.send_labels(labels["states"], labels["actions"], labels["request_id"])
        self.get_logger().info(f"page: {len(labels['states'])} label(s) for request {labels['request_id']}")
        return self._page_answer(msg_id, "the planner")

    def history(self, review_id: str | None = None) -> dict:
        """The planner's answer on /planner/history: the reviews, or one review's records. Raises
        Unavailable when the planner does not answer, LwmError when it cannot read its ledger."""
        asked = {"version": messages.version("history_request")}
        answer = self.history_call(asked if review_id is None else {**asked, "review_id": review_id})
        if not answer["ok"]:
            raise LwmError(answer["error"])
        return answer

    def page_history(self, review_id: str | None) -> dict:
        """The reviews the planner keeps, or one review's records, as the page lists them."""
        try:
            found = self.history(review_id)
        except (Unavailable, LwmError) as exc:  # the planner is not up yet, or cannot read its ledger now
            return {"reviews": [], "records": [], "note": f"no history from the planner: {exc}"}
        if review_id is None:
            return {"ledger": found["ledger"], "reviews": found["reviews"]}
        return {"ledger": found["ledger"], "review_id": review_id, "records": history_view(found["records"])}

    def on_page_manual(self, descriptions: list[str]) -> str:
        msg_id = self.publish_manual({"descriptions": descriptions, "source": "human"})
        self.get_logger().info("page: a new manual")
        return self._page_answer(msg_id, "the simulator")

    def close(self) -> None:
        if self.page is not None:
            self.page.close()

    def on_report(self, report: dict) -> None:
        self.reported.add(report["review_id"])
        if self.executing == report["review_id"]:
            self.executing = None
        if self.page is not None:
            self.page.push("report", report_view(report))
        print(
            f"SUMMARY review {report['review_id']}: plan {report['plan_id']} after {report['revisions']} revision(s); "
            f"imagined return {report['imagined_return']:+.2f}, real return {report['real_return']:+.2f}, "
            f"{report['steps']} steps, {report['outcome']}, reviews asked again {report.get('reviews_asked', 0)}",
            flush=True,
        )
        if not self.scripted or report["review_id"] in self.reports:
            return
        self.reports.add(report["review_id"])
        if len(self.reports) >= self.episodes:
            self.stop.set()
            return
        # The operator's part: start the next episode (the next seed) of the same game.
        seed = Episode.parse(report["review_id"]).seed + 1
        self.work.put(lambda: self.env_reset({"seed": seed}))

    def _work(self) -> None:
        while True:
            job = self.work.get()
            try:
                job()
            except Exception as exc:  # a failed answer must not end the review
                self.report_error("scripted reviewer", exc)

    def read_commands(self) -> None:
        for line in sys.stdin:
            line = line.strip()
            try:
                self.command(line)
            except Exception as exc:  # a typo must not end the review
                print(f"not sent: {exc}", flush=True)

    def command(self, line: str) -> None:
        if line == "m":
            print("three descriptions, one per line:", flush=True)
            manual = [sys.stdin.readline().strip() for _ in range(3)]
            self.publish_manual({"descriptions": manual, "source": "human"})
            return
        if line.startswith("s "):
            self.show_state(int(line.split()[1]))
            return
        if line == "f" and self.plan is not None:
            show(self.plan, frames="all")
            return
        if line == "n" or line.startswith("n "):
            seed = line.split()[1:]
            print(self.next_episode(int(seed[0]) if seed else None), flush=True)
            return
        if line == "restart":
            print(self.next_episode(restart=True), flush=True)
            return
        if line.startswith("l "):
            pairs = [] if line[2:].strip() == "-" else [p.split(":") for p in line[2:].split()]
            self.send_labels([int(s) for s, _ in pairs], [int(a) for _, a in pairs])
            return
        if not line or self.plan is None:
            return
        base = {"review_id": self.plan["review_id"], "plan_id": self.plan["plan_id"]}
        if line == "a":
            self.publish_feedback({**base, "decision": "approve"})
        elif line == "r":
            self.publish_feedback({**base, "decision": "reject"})
        elif line == "x":
            self.publish_feedback({**base, "decision": "abort"})
        elif line == "stop":
            self.publish_feedback({**base, "decision": "stop"})
        elif line.split()[0] == "i":
            rounds = line.split()[1:]
            self.publish_feedback({**base, "decision": "imitate", **({"rounds": int(rounds[0])} if rounds else {})})
        elif line.startswith("c "):
            fixes = [{"step": int(s), "action": int(a)} for s, a in (p.split(":") for p in line[2:].split())]
            self.publish_feedback({**base, "decision": "corrections", "corrections": fixes})
        else:
            print(
                "unknown command; a | r | c STEP:ACTION ... | i [ROUNDS] | l STATE:ACTION ... | x | stop | m | "
                "n [SEED] | restart",
                flush=True,
            )


def show(plan: dict, quiet: bool = False, frames: str = "ends") -> None:
    print("\n" + plan_text(plan, "none" if quiet else frames), flush=True)


def main() -> int:
    stop = threading.Event()
    return run(lambda: HumanNode(stop), stop)


if __name__ == "__main__":
    raise SystemExit(main())

"""The review in a terminal: each plan's imagined frames (ASCII), rewards, confidence and sampled
futures are printed, and the person answers on stdin:

    a                 approve (the planner's policy then acts in the real game)
    r                 reject (the planner imagines again)
    c STEP:ACTION ... corrections, e.g. "c 1:3 2:right" (actions 0 up, 1 down, 2 left, 3 right, 4 stay,
                      by number or name)
    i [ROUNDS]        teach: rounds of learning in imagination, each asking you to label a few
                      imagined states (where the agent is unsure what the manual means)
    stop              end the teaching under way (the agent keeps what it learnt, re-plans),
                      or the execution of an approved plan (no further move; a report follows)
    l STATE:ACTION ...  label states of the current label request ("l -" sends none); one answer
                      per request, before the planner stops waiting (the request's timeout)
    x                 abort: execute nothing
    u                 undo: take back your newest change still in force in this review (a correction,
                      a teaching with its labels, demonstrations, or a manual or answer), newest first
    m                 the manual under review, then a new one: three descriptions, one per line
                      (published on /feedback/manual)
    q N               answer the plan's question about the manual with choice N (1, 2 or 3): the
                      fact joins the manual, and the agent re-plans under it
    n [SEED]          the next episode of this game (the next seed, or SEED): a fresh review
    restart           this episode again from its start (same board and seed), as a fresh review
    f                 every frame of the plan (a plan shows its start and last board, a line per step);
                      once its report is out, every step of the real episode beside the plan
    s N               state N of the label request, beside the state a step before it

A command may be typed in full (approve, reject, abort, teach, manual, next, ...). A line that is
no command, or whose arguments are not the command's, is answered in plain words and sends
nothing. Every answer, label batch and manual gets the receiving node's answer on /lwm/acks, printed here:
taken, or refused with the reason. Answers are signed as reviewer `reviewer` (default: terminal).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TYPE_CHECKING

from lwm_models.agent.review_text import progress_text, report_text, state_text
from lwm_models.agent.review_view import answered_manual, label_request_view
from lwm_models.messenger.constants import ACTION_NAMES
from lwm_nodes.reviewer import Reviewer, show

if TYPE_CHECKING:
    from lwm_nodes.human_node import HumanNode

PROMPT = (
    "answer: a approve | r reject | c STEP:ACTION ... correct | i [ROUNDS] teach | x abort | u undo | m manual | "
    "n next episode | restart this episode | f every frame | stop (teaching or the agent's play)"
    " | q N answer the question"
)
USAGE = (
    "unknown command; a | r | c STEP:ACTION ... | i [ROUNDS] | l STATE:ACTION ... | x | u | stop | m | q N | "
    "n [SEED] | restart"
)
NODE_WORDS = {"lwm_world_model": "world-model server"}  # how the terminal names who answered
DECISIONS = {"a": "approve", "r": "reject", "x": "abort", "stop": "stop"}
# A command typed in full means what its letter does.
WORDS = {"approve": "a", "reject": "r", "abort": "x", "correct": "c", "teach": "i", "imitate": "i", "label": "l",
         "manual": "m", "next": "n", "frames": "f", "show": "s", "answer": "q", "undo": "u"}  # fmt: skip
ACTION_WORDS = {name: k for k, name in enumerate(ACTION_NAMES)}


def _number(word: str, what: str, example: str) -> int:
    if not word.isdigit():
        raise ValueError(f"{what} is a number, e.g. {example}; got {word!r}")
    return int(word)


def _pairs(words: list[str], what: str, example: str) -> list[tuple[int, int]]:
    """STEP:ACTION (or STATE:ACTION) pairs; the action as a number or its name ("3:right")."""
    out = []
    for word in words:
        left, colon, right = word.partition(":")
        action = ACTION_WORDS.get(right.lower(), None)
        if not colon or not left.isdigit() or (action is None and not right.isdigit()):
            raise ValueError(
                f"{what} is {example}: a number, a colon and an action (0 up, 1 down, 2 left, 3 right, 4 stay, "
                f"or its name); got {word!r}"
            )
        out.append((int(left), action if action is not None else int(right)))
    return out


def parse_command(line: str) -> tuple[str, list]:
    """A typed line as (command letter, its arguments); ValueError in plain words for a line that
    is no command or whose arguments are not what the command takes."""
    words = line.split()
    if not words:
        return "", []
    head = WORDS.get(words[0].lower(), words[0].lower())
    rest = words[1:]
    if head in ("a", "r", "x", "stop", "m", "f", "restart", "u"):
        if rest:
            raise ValueError(f"{words[0]} takes nothing after it; got {' '.join(rest)!r}")
        return head, []
    if head == "c":
        if not rest:
            raise ValueError("say which steps to correct, e.g. c 3:1 or c 3:right")
        return head, _pairs(rest, "a correction", "STEP:ACTION, e.g. c 3:1 or c 3:right")
    if head == "l":
        if rest == ["-"]:
            return head, []
        if not rest:
            raise ValueError("label states as l STATE:ACTION ..., or l - for none")
        return head, _pairs(rest, "a label", "STATE:ACTION, e.g. l 0:3 or l 0:right")
    if head in ("i", "n", "s", "q"):
        if len(rest) > 1:
            raise ValueError(f"{words[0]} takes one number at most; got {' '.join(rest)!r}")
        if head in ("s", "q") and not rest:
            raise ValueError("s takes a state number, e.g. s 2" if head == "s" else "q takes a choice, e.g. q 1")
        if head == "q":
            return head, rest  # the question's own check says which choices there are
        example = {"i": "i 2 (rounds)", "n": "n 7 (a seed)", "s": "s 2 (a state)"}[head]
        return head, [_number(rest[0], "it", example)] if rest else []
    raise ValueError(USAGE)


class TerminalReviewer(Reviewer):
    def __init__(self, node: HumanNode) -> None:
        self.node = node
        self.report: dict | None = None  # the open review's report, once it is out (`f` shows it)

    def start(self) -> None:
        threading.Thread(target=self.read_commands, daemon=True).start()

    def on_plan(self, plan: dict) -> None:
        if self.report is not None and self.report["review_id"] != plan["review_id"]:
            self.report = None
        show(plan, self.node.quiet)
        print(PROMPT, flush=True)

    def on_progress(self, progress: dict) -> None:
        # What the world model read (round 0) and when learning ends: a line a round would bury the plan.
        if (progress["round"] == 0 and progress.get("roles")) or progress["done"]:
            print(progress_text(progress), flush=True)

    def on_label_request(self, request: dict, expires: float | None) -> None:
        n = len(request["observations"])
        waits = f"{expires - time.time():.0f} s" if expires is not None else "with no deadline"
        print(
            f"label request {request['request_id']} (round {request['round']}/{request['rounds']}): the agent "
            f"asks about {n} imagined state(s); label them with l STATE:ACTION ... (states 0..{n - 1}), l - for "
            f"none; s N shows state N; the planner waits {waits}; stop ends the teaching",
            flush=True,
        )
        for k in range(n):
            self.show_state(k)

    def on_report(self, report: dict) -> None:
        self.report = report
        print("\n" + report_text(report, "none" if self.node.quiet else "ends"), flush=True)

    def on_notice(self, text: str) -> None:
        super().on_notice(text)
        if self.node.plan is not None:
            print(PROMPT, flush=True)

    def on_ack(self, ack: dict, sent: dict) -> None:
        who = NODE_WORDS.get(ack["node"], ack["node"].removeprefix("lwm_"))
        print(f"{who}: {ack['reason']}" if ack["ok"] else f"REFUSED by the {who}: {ack['reason']}", flush=True)

    def show_state(self, k: int) -> None:
        """State k of the label request, beside the state a step before it in its episode."""
        request = self.node.request
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

    def read_commands(self) -> None:
        for line in sys.stdin:
            try:
                self.command(line.strip())
            except Exception as exc:  # a typo must not end the review
                print(f"not sent: {exc}", flush=True)

    def command(self, line: str) -> None:
        node = self.node
        head, args = parse_command(line)
        if head == "m":
            if node.plan is not None:
                shown = "\n".join(f"  {k}. {d}" for k, d in enumerate(node.plan["manual"], 1))
                print(f"the manual under review (v{node.plan['manual_version']}):\n{shown}", flush=True)
            print("three descriptions, one per line:", flush=True)
            manual = [sys.stdin.readline().strip() for _ in range(3)]
            node.publish_manual({"descriptions": manual, "source": "human"})
        elif head == "q":
            node.publish_manual(answered_manual(node.plan, args))
        elif head == "s":
            self.show_state(args[0])
        elif head == "f":
            if self.report is not None:
                print(report_text(self.report, "all"), flush=True)
            elif node.plan is None:
                raise ValueError("there is no plan yet to show")
            else:
                show(node.plan, frames="all")
        elif head == "n":
            print(node.next_episode(args[0] if args else None), flush=True)
        elif head == "restart":
            print(node.next_episode(restart=True), flush=True)
        elif head == "l":
            node.send_labels([s for s, _ in args], [a for _, a in args])
        elif head == "u":
            _, who, what = node.undo()
            print(f"taking back {what}; {who} answers", flush=True)
        elif not head:
            return
        elif node.plan is None:
            raise ValueError("there is no plan under review yet")
        elif head in DECISIONS:
            self.decide(DECISIONS[head])
        elif head == "i":
            self.decide("imitate", **({"rounds": args[0]} if args else {}))
        elif head == "c":
            self.decide("corrections", corrections=[{"step": s, "action": a} for s, a in args])

    def decide(self, decision: str, **fields) -> None:
        plan = self.node.plan
        self.node.publish_feedback(
            {"review_id": plan["review_id"], "plan_id": plan["plan_id"], "decision": decision, **fields}
        )

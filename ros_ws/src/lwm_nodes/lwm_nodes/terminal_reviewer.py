"""The review in a terminal: each plan's imagined frames (ASCII), rewards, confidence and sampled
futures are printed, and the person answers on stdin:

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
    q N               answer the plan's question about the manual with choice N (1, 2 or 3): the
                      fact joins the manual, and the agent re-plans under it
    n [SEED]          the next episode of this game (the next seed, or SEED): a fresh review
    restart           this episode again from its start (same board and seed), as a fresh review
    f                 every frame of the plan (a plan shows its start and last board, a line per step)
    s N               state N of the label request, beside the state a step before it

Every answer, label batch and manual gets the receiving node's answer on /lwm/acks, printed here:
taken, or refused with the reason. Answers are signed as reviewer `reviewer` (default: terminal).
"""

from __future__ import annotations

import sys
import threading
import time
from typing import TYPE_CHECKING

from lwm_models.agent.review_text import progress_text, state_text
from lwm_models.agent.review_view import answered_manual, label_request_view
from lwm_nodes.reviewer import Reviewer, show

if TYPE_CHECKING:
    from lwm_nodes.human_node import HumanNode

PROMPT = (
    "answer: a approve | r reject | c STEP:ACTION ... correct | i [ROUNDS] teach | x abort | m manual | "
    "n next episode | restart this episode | f every frame | stop (teaching or the agent's play)"
    " | q N answer the question"
)
USAGE = (
    "unknown command; a | r | c STEP:ACTION ... | i [ROUNDS] | l STATE:ACTION ... | x | stop | m | q N | n [SEED] | "
    "restart"
)
NODE_WORDS = {"lwm_world_model": "world-model server"}  # how the terminal names who answered
DECISIONS = {"a": "approve", "r": "reject", "x": "abort", "stop": "stop"}


class TerminalReviewer(Reviewer):
    def __init__(self, node: HumanNode) -> None:
        self.node = node

    def start(self) -> None:
        threading.Thread(target=self.read_commands, daemon=True).start()

    def on_plan(self, plan: dict) -> None:
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
        words = line.split()
        if line == "m":
            print("three descriptions, one per line:", flush=True)
            manual = [sys.stdin.readline().strip() for _ in range(3)]
            node.publish_manual({"descriptions": manual, "source": "human"})
        elif words[:1] == ["q"]:
            node.publish_manual(answered_manual(node.plan, words[1:]))
        elif words[:1] == ["s"] and len(words) == 2:
            self.show_state(int(words[1]))
        elif line == "f" and node.plan is not None:
            show(node.plan, frames="all")
        elif words[:1] == ["n"]:
            print(node.next_episode(int(words[1]) if len(words) > 1 else None), flush=True)
        elif line == "restart":
            print(node.next_episode(restart=True), flush=True)
        elif words[:1] == ["l"] and len(words) > 1:
            pairs = [] if words[1:] == ["-"] else [w.split(":") for w in words[1:]]
            node.send_labels([int(s) for s, _ in pairs], [int(a) for _, a in pairs])
        elif not line or node.plan is None:
            return
        elif line in DECISIONS:
            self.decide(DECISIONS[line])
        elif words[0] == "i":
            self.decide("imitate", **({"rounds": int(words[1])} if len(words) > 1 else {}))
        elif words[0] == "c":
            fixes = [{"step": int(s), "action": int(a)} for s, a in (w.split(":") for w in words[1:])]
            self.decide("corrections", corrections=fixes)
        else:
            print(USAGE, flush=True)

    def decide(self, decision: str, **fields) -> None:
        plan = self.node.plan
        self.node.publish_feedback(
            {"review_id": plan["review_id"], "plan_id": plan["plan_id"], "decision": decision, **fields}
        )

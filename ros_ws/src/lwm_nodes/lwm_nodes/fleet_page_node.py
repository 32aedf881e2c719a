"""The fleet page (`./run_nodes.sh --agents N --page PORT`): one page for a person reviewing a fleet.

It shows a queue of the agents, the ones waiting for the person first (a plan to answer, states
to label), the longest waiting at the top, each with what it is doing, its plan's imagined return
and risk, its manual's version, and a link to its own review page (agent K's human-feedback node
serves it on PORT+K, where the person answers that agent's plans). A manual written on the fleet
page goes to every agent (/feedback/manual: the world-model server re-reads it once and every
agent re-plans) or to one (/agentK/feedback/manual), signed as the person; the world-model
server's answer is shown beside it.

It listens, per agent, to env/state, planner/progress, planner/plan, planner/label_request,
review/feedback and planner/report, and to lwm/status; it sends nothing but manuals.
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

from lwm_nodes.common import FEEDBACK, LATCHED, Answers, JsonNode, agent_topic, run
from lwm_nodes.review_page import ReviewPage, reply
from lwm_nodes.trust import Signer

FLEET_PAGE = Path(__file__).with_name("web") / "fleet.html"
ANSWER_WAIT_S = 8.0


class AgentView:
    """What the fleet page knows of one agent, from its topics."""

    def __init__(self, name: str, page: str) -> None:
        self.name, self.page = name, page
        self.episode = ""
        self.plan: dict | None = None
        self.plan_at = 0.0  # monotonic: when the plan came
        self.request: dict | None = None
        self.request_at = 0.0
        self.progress: dict | None = None
        self.approved: set[str] = set()  # reviews whose plan was approved
        self.report: dict | None = None
        self.manual_version = 0

    def view(self, now: float) -> dict:
        """The queue's row: `waiting` seconds when the agent waits for the person, else None."""
        row = {"agent": self.name, "page": self.page, "episode": self.episode, "manual_version": self.manual_version}
        review = self.episode
        plan = self.plan if self.plan and self.plan["review_id"] == review else None
        request = self.request if self.request and self.request["review_id"] == review else None
        if plan is not None:
            futures = plan["futures"]
            row["plan"] = {
                "plan_id": plan["plan_id"],
                "reason": plan.get("reason", ""),
                "imagined_return": plan["imagined_return"],
                "death_share": futures["death_share"],
                "manual_version": plan["manual_version"],
            }
        waiting = None
        if self.report is not None and self.report["review_id"] == review:
            r = self.report
            doing = f"done: {r['outcome'].replace('_', ' ')}, real return {r['real_return']:+.2f}"
        elif review in self.approved:
            doing = "playing the approved plan in the real game"
        elif request is not None and request["request_id"] > 0 and self.request_at >= self.plan_at:
            n = len(request["observations"])
            doing = f"asks you to label {n} states (round {request['round']} of {request['rounds']})"
            waiting = now - self.request_at
        elif plan is not None:
            doing = f"plan {plan['plan_id']} waits for your answer"
            waiting = now - self.plan_at
        elif self.progress is not None and self.progress["review_id"] == review and not self.progress["done"]:
            doing = f"teaching itself from the manual: round {self.progress['round']} of {self.progress['rounds']}"
        else:
            doing = "preparing its first plan"
        row["doing"] = doing
        row["waiting_s"] = None if waiting is None else round(waiting, 1)
        return row


class FleetPageNode(JsonNode):
    def __init__(self) -> None:
        super().__init__("fleet_page")
        p = self.declare_parameter
        agents = [a.strip("/") for a in p("agents", [""]).value if a.strip("/")]
        port = int(p("page_port", 0).value)
        host = p("page_host", "127.0.0.1").value
        first_agent_port = int(p("first_agent_port", 0).value)  # agent K's review page: this + K - 1
        if not agents or not port:
            raise ValueError("the fleet page needs `agents` (their namespaces) and a `page_port`")
        self.lock = threading.Lock()
        self.agents = {
            a: AgentView(a, f"http://{host}:{first_agent_port + i}/" if first_agent_port else "")
            for i, a in enumerate(agents)
        }
        self.signer = Signer(self, "")
        self.answers = Answers(self)
        self.manual_to = {
            None: self.answers.sender(
                self.signer.publisher(self.json_publisher("feedback/manual", "manual", LATCHED), "manual")
            )
        }
        for a in agents:
            publish = self.json_publisher(agent_topic(a, "feedback/manual"), "manual", LATCHED)
            self.manual_to[a] = self.answers.sender(self.signer.publisher(publish, "manual"))
            for topic, kind, field, qos in (
                ("env/state", "state", "state", LATCHED),
                ("planner/progress", "progress", "progress", LATCHED),
                ("planner/plan", "plan", "plan", LATCHED),
                ("planner/label_request", "label_request", "request", LATCHED),
                ("review/feedback", "review_feedback", "feedback", FEEDBACK),
                ("planner/report", "execution_report", "report", LATCHED),
                ("lwm/status", "status", "status", LATCHED),
            ):
                self.json_subscription(
                    agent_topic(a, topic), kind, lambda m, a=a, f=field: self.on_message(a, f, m), qos
                )
        self.page = ReviewPage(
            host,
            port,
            on_feedback=_answer_on_the_agents_page,
            on_manual=self.on_manual,
            on_labels=_answer_on_the_agents_page,
            history=lambda _: {"reviews": [], "note": "each agent's history is on its own page"},
            on_reviewer=self.on_reviewer,
            reviewer="",
            html=FLEET_PAGE,
            kinds=("fleet", "reviewer"),
        )
        self.create_timer(1.0, self.push)  # the waiting times grow: the queue is re-sent every second
        print(f"PAGE fleet page at {self.page.url}", flush=True)

    def on_message(self, agent: str, field: str, msg: dict) -> None:
        view, now = self.agents[agent], time.monotonic()
        with self.lock:
            if field == "state":
                view.episode = msg["episode_id"]
            elif field == "plan":
                view.plan, view.plan_at = msg, now
            elif field == "request":
                view.request, view.request_at = msg, now
            elif field == "progress":
                view.progress = msg
            elif field == "feedback" and msg["decision"] == "approve":
                view.approved.add(msg["review_id"])
            elif field == "report":
                view.report = msg
            elif field == "status":
                view.manual_version = msg["manual_version"]
        self.push()

    def queue(self) -> list[dict]:
        """The agents, those waiting for the person first (longest waiting at the top)."""
        now = time.monotonic()
        with self.lock:
            rows = [v.view(now) for v in self.agents.values()]
        return sorted(rows, key=lambda r: (r["waiting_s"] is None, -(r["waiting_s"] or 0), r["agent"]))

    def push(self) -> None:
        self.page.push("fleet", {"agents": self.queue()})

    def health(self) -> tuple[str, dict[str, object]]:
        rows = self.queue()
        waiting = [r["agent"] for r in rows if r["waiting_s"] is not None]
        return f"{len(waiting)} of {len(rows)} agents wait for the person", {"waiting": ", ".join(waiting) or "none"}

    def on_manual(self, body: dict) -> str:
        """A manual for every agent (no `agent`) or one; the world-model server's words back."""
        agent = body.get("agent") or None
        if agent not in self.manual_to:
            raise ValueError(f"no agent {agent!r} here (the fleet: {', '.join(self.agents)})")
        if not self.signer.reviewer:
            raise ValueError("say who you are first: your manual is signed with your own key")
        msg_id = self.manual_to[agent]({"descriptions": body["descriptions"], "source": "human"})
        self.get_logger().info(f"fleet page: a manual for {agent or 'every agent'}")
        return reply(self.answers.wait(msg_id, ANSWER_WAIT_S), "the world-model server", ANSWER_WAIT_S)

    def on_reviewer(self, body: dict) -> str:
        who = self.page.become(body, self.signer)
        return f"you write manuals as {who}: they are signed with your own key"

    def close(self) -> None:
        self.page.close()


def _answer_on_the_agents_page(body: dict) -> str:
    raise ValueError("answer an agent's plan on its own page (the link in its row)")


def main() -> int:
    return run(FleetPageNode)


if __name__ == "__main__":
    raise SystemExit(main())

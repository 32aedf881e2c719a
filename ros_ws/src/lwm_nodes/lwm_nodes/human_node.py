"""Human-feedback node: shows each plan to a person and publishes what they answer.

Interactive (a terminal): the plan's imagined frames (ASCII), rewards and confidence, then
    a                 approve (the planner executes the plan in the real game)
    r                 reject (the planner re-plans)
    c STEP:ACTION ... corrections, e.g. "c 1:3 2:3" (actions 0 up, 1 down, 2 left, 3 right, 4 stay)
    m                 a new manual: three descriptions, one per line
Scripted (parameter scripted:=true): the simulated human of the paper, knowing the true game:
it corrects the plan's actions with go_to_goal's, approves once the imagined return reaches
`approve_return` (or after `max_rounds`), prints a summary when the report arrives and exits.
"""

from __future__ import annotations

import sys
import threading

import numpy as np

from lwm_models.agent.expert import expert_actions, role_ids
from lwm_models.data.splits import load_split
from lwm_models.messenger.constants import ACTION_NAMES
from lwm_models.messenger.render import render_ascii
from lwm_nodes.common import FEEDBACK, LATCHED, JsonNode, run


class HumanNode(JsonNode):
    def __init__(self, stop: threading.Event | None = None) -> None:
        super().__init__("human_feedback")
        self.scripted = bool(self.declare_parameter("scripted", False).value)
        self.approve_return = float(self.declare_parameter("approve_return", 1.0).value)
        self.max_rounds = int(self.declare_parameter("max_rounds", 3).value)
        self.max_corrections = int(self.declare_parameter("max_corrections", 8).value)
        self.stop = stop
        self.game = None
        self.rounds = 0
        self.plan: dict | None = None
        self.publish_feedback = self.json_publisher("/review/feedback", "review_feedback", FEEDBACK)
        self.json_subscription("/env/state", "state", self.on_state, LATCHED)
        self.json_subscription("/planner/plan", "plan", self.on_plan, LATCHED)
        self.json_subscription("/planner/report", "execution_report", self.on_report, LATCHED)
        if not self.scripted:
            threading.Thread(target=self.read_commands, daemon=True).start()

    def on_state(self, payload: dict) -> None:
        g = payload["game"]
        self.game = load_split(g["split"])[g["index"]]

    def on_plan(self, plan: dict) -> None:
        if (
            self.plan is not None
            and plan["plan_id"] <= self.plan["plan_id"]
            and plan["review_id"] == self.plan["review_id"]
        ):
            return  # a latched repeat
        self.plan = plan
        self.rounds += 1
        show(plan)
        if self.scripted:
            self.answer_scripted(plan)
        else:
            print("answer: a (approve) | r (reject) | c STEP:ACTION ... (correct) | m (new manual)", flush=True)

    def answer_scripted(self, plan: dict) -> None:
        base = {"review_id": plan["review_id"], "plan_id": plan["plan_id"]}
        if plan["imagined_return"] >= self.approve_return or self.rounds >= self.max_rounds or self.game is None:
            self.publish_feedback({**base, "decision": "approve", "comment": f"round {self.rounds}"})
            print(f"scripted human: approve plan {plan['plan_id']}", flush=True)
            return
        obs = np.asarray(plan["observations"], dtype=np.uint8)
        wanted = expert_actions(obs[:-1] if len(obs) > 1 else obs, role_ids(self.game), 1, 0) if len(obs) > 1 else []
        fixes = [{"step": t + 1, "action": int(a)} for t, a in enumerate(wanted) if a != plan["actions"][t]]
        if not fixes:
            self.publish_feedback({**base, "decision": "approve"})
            print(f"scripted human: approve plan {plan['plan_id']} (nothing to correct)", flush=True)
            return
        fixes = fixes[: self.max_corrections]
        self.publish_feedback({**base, "decision": "corrections", "corrections": fixes})
        print(f"scripted human: {len(fixes)} correction(s) to plan {plan['plan_id']}", flush=True)

    def on_report(self, report: dict) -> None:
        print(
            f"SUMMARY review {report['review_id']}: plan {report['plan_id']} after {report['revisions']} revision(s); "
            f"imagined return {report['imagined_return']:+.2f}, real return {report['real_return']:+.2f}, "
            f"{report['steps']} steps, {report['outcome']}",
            flush=True,
        )
        if self.scripted and self.stop is not None:
            self.stop.set()

    def read_commands(self) -> None:
        for line in sys.stdin:
            line = line.strip()
            if not line or self.plan is None:
                continue
            base = {"review_id": self.plan["review_id"], "plan_id": self.plan["plan_id"]}
            try:
                if line == "a":
                    self.publish_feedback({**base, "decision": "approve"})
                elif line == "r":
                    self.publish_feedback({**base, "decision": "reject"})
                elif line.startswith("c "):
                    fixes = [{"step": int(s), "action": int(a)} for s, a in (p.split(":") for p in line[2:].split())]
                    self.publish_feedback({**base, "decision": "corrections", "corrections": fixes})
                elif line == "m":
                    print("three descriptions, one per line:", flush=True)
                    manual = [sys.stdin.readline().strip() for _ in range(3)]
                    self.publish_feedback({**base, "decision": "manual", "manual": manual})
                else:
                    print("unknown command; a | r | c STEP:ACTION ... | m", flush=True)
            except Exception as exc:  # a typo must not end the review
                print(f"not sent: {exc}", flush=True)


def show(plan: dict) -> None:
    print(
        f"\n=== plan {plan['plan_id']} (review {plan['review_id']}, manual v{plan['manual_version']}): "
        f"imagined return {plan['imagined_return']:+.2f} ===",
        flush=True,
    )
    for t, obs in enumerate(plan["observations"]):
        if t == 0:
            print("start")
        else:
            print(
                f"step {t}: {ACTION_NAMES[plan['actions'][t - 1]]}, reward {plan['rewards'][t - 1]:+.1f}, "
                f"confidence {plan['confidence'][t - 1]:.2f}"
            )
        print(render_ascii(np.asarray(obs, dtype=np.uint8)))
    sys.stdout.flush()


def main() -> int:
    stop = threading.Event()
    return run(lambda: HumanNode(stop), stop)


if __name__ == "__main__":
    raise SystemExit(main())

"""The scripted reviewer (parameter scripted:=true, `./run_nodes.sh --scripted`): the paper's
simulated human, the expert reading the true manual (lwm_models.agent.reviewer). It labels every
state a teaching round asks about, corrects, and never approves a plan whose shown trajectory dies.
When an execution's report comes it starts the next episode (the next seed), as an operator would,
and after `episodes` reports it stops the node, which ends the launcher's run with its summary.
With language:=true its first answer in each review is language feedback: the true manual in other
words, published on /feedback/manual (texts:= the description files to draw them from; default:
the project's generator). Parameters: teach, approve_return, max_death_share, max_rounds (the
reviewer's, lwm_models/agent/reviewer.py), episodes, language, texts, questions.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from lwm_models.agent.reviewer import ScriptedReviewer
from lwm_models.data.episode import Episode
from lwm_nodes.reviewer import Reviewer, show

if TYPE_CHECKING:
    from lwm_nodes.human_node import HumanNode


class SimulatedReviewer(Reviewer):
    default_name = "scripted"

    def __init__(self, node: HumanNode) -> None:
        self.node = node
        p = node.declare_parameter
        self.teach = p("teach", "online_il").value
        self.approve_return = float(p("approve_return", 1.0).value)
        self.max_death_share = float(p("max_death_share", 0.5).value)
        self.max_rounds = int(p("max_rounds", 4).value)
        self.episodes = int(p("episodes", 1).value)  # reviews before it stops
        self.language = bool(p("language", False).value)  # a reworded manual first
        self.texts = p("texts", "").value  # comma-separated description files for the rewording
        self.questions = bool(p("questions", False).value)  # answers the reading's questions first
        self.pools = None
        self.expert: ScriptedReviewer | None = None
        self.reports: set[str] = set()

    def on_game(self, game, split: str) -> None:
        self.expert = ScriptedReviewer(
            game, self.teach, self.approve_return, self.max_death_share, self.max_rounds, language=self.language
        )

    def on_plan(self, plan: dict) -> None:
        show(plan, self.node.quiet)
        # Its answer may imagine through /lwm/imagine (filtered BC), which the executor answers.
        self.node.work.put(lambda: self.answer(plan))

    def answer(self, plan: dict) -> None:
        if self.expert is None:
            print("scripted human: no game state yet; cannot review", flush=True)
            return
        if self.expert.wants_to_speak(plan):
            self.speak(plan)
            return
        fact = self.expert.answer(plan) if self.questions else None
        if fact is not None:  # the answer is part of the manual: the planner re-plans under it
            facts = [*plan.get("facts", []), fact]
            self.node.publish_manual({"descriptions": plan["manual"], "facts": facts, "source": "human"})
            asked, at = plan["questions"][0]["text"], time.time()
            # The wall time lets benchmarks/review_loop.py time the answer -> revised plan.
            print(
                f"scripted human: answered {asked!r} with {fact['value']} on plan {plan['plan_id']} at {at:.3f}",
                flush=True,
            )
            return
        feedback = self.expert.review(plan, self.node.imaginer)
        self.node.publish_feedback(feedback)
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
            from lwm_models.text.stress import description_pools

            self.pools = description_pools(self.texts.split(",")) if self.texts else DescriptionPools.generated()
        seed = Episode.parse(plan["review_id"]).seed
        manual = self.expert.reworded_manual(self.pools, self.node.split, plan["manual"], seed)
        self.node.publish_manual({"descriptions": manual, "source": "human"})
        # The wall time lets benchmarks/review_loop.py time feedback -> revised plan.
        print(f"scripted human: manual feedback on plan {plan['plan_id']} at {time.time():.3f}", flush=True)

    def on_label_request(self, request: dict, expires: float | None) -> None:
        if self.expert is None:
            return
        self.node.publish_labels(self.expert.label(request))
        if not self.node.quiet or request["round"] == request["rounds"]:
            n = len(request["observations"])
            print(f"scripted human: labelled {n} states of round {request['round']}/{request['rounds']}", flush=True)

    def on_report(self, report: dict) -> None:
        if report["review_id"] in self.reports:
            return
        self.reports.add(report["review_id"])
        if len(self.reports) >= self.episodes:
            self.node.stop.set()
            return
        self.node.work.put(lambda: print(self.node.next_episode(), flush=True))

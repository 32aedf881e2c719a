"""The review loop's core without ROS: the world-model server's sessions, the imagination client, manual
versions, the scripted reviewer and the review state machine, all with real components in one
process (the ROS tests run the same code across processes)."""

from __future__ import annotations

import tempfile
import threading
import time

import numpy as np
import pytest
import torch
from game_fixtures import MANUAL, OBS

from lwm_models import messages
from lwm_models.agent.agent import FeedbackError
from lwm_models.agent.imaginer import ImagineError, LocalImaginer, ServiceImaginer, in_process
from lwm_models.agent.learning import Budget
from lwm_models.agent.policy import load_policy
from lwm_models.agent.review import Ports, ReviewConfig, ReviewLoop
from lwm_models.agent.reviewer import ScriptedReviewer
from lwm_models.agent.self_teaching import Teaching
from lwm_models.data.session import GameSession
from lwm_models.ledger import Ledger
from lwm_models.messenger.observation import InvalidObservation, check_observation
from lwm_models.world.frozen_text import FrozenTextEncoder
from lwm_models.world.imagine import imagine
from lwm_models.world.model_server import RequestError, WorldModelServer
from lwm_models.world.shipped import SHIPPED, SHIPPED_POLICY


@pytest.fixture(scope="module")
def encoder():
    return FrozenTextEncoder()


@pytest.fixture(scope="module")
def sim(encoder):
    torch.set_num_threads(1)
    s = WorldModelServer(encoder=encoder)
    s.set_manual(MANUAL, "test")
    return s


def test_a_session_imagines_what_one_shot_imagination_does(sim):
    actions = np.array([[3, 3, 1, 1, 2, 4], [1, 1, 3, 3, 4, 0]])
    one_shot = imagine(sim.model, sim._batch, np.array(OBS), n=2, actions=actions, max_steps=6, seed=7)
    opened = sim.handle({"op": "open", "observation": OBS, "n": 2, "max_steps": 6, "seed": 7})
    assert opened["manual_version"] == sim.manual_version and opened["active"] == [0, 1]
    active, t = opened["active"], 0
    while active:
        t += 1
        step = sim.handle({"op": "step", "session": opened["session"], "actions": actions[active, t - 1].tolist()})
        for k, i in enumerate(step["stepped"]):
            assert step["observations"][k] == one_shot.observations[i, t].tolist()
            assert step["rewards"][k] == one_shot.rewards[i, t] and step["dones"][k] == one_shot.dones[i, t]
        active = step["active"]
        if step["finished"]:
            break
    sim.handle({"op": "close", "session": opened["session"]})
    with pytest.raises(RequestError, match="no imagination session"):
        sim.handle({"op": "step", "session": opened["session"], "actions": [0]})


def test_remote_and_local_imagination_agree(sim):
    """The same policy through the service's JSON path and in process: the same trajectories."""
    policy = load_policy(SHIPPED_POLICY)
    from lwm_models.agent.agent import PlanReviewAgent

    remote = ServiceImaginer(in_process(sim))
    local = LocalImaginer(sim.model, sim._batch)
    a = PlanReviewAgent(policy, sim.encoder, remote, MANUAL).make_plan(np.array(OBS), 1, seed=3)
    b = PlanReviewAgent(policy, sim.encoder, local, MANUAL).make_plan(np.array(OBS), 1, seed=3)
    assert a.observations == b.observations and a.actions == b.actions and a.futures == b.futures
    assert a.manual_version == sim.manual_version and remote.stats.calls > len(a.actions)


@pytest.mark.parametrize(
    "obs, why",
    [
        ([[2, 2, 7], [2, 7, 2], [11, 7, 7], [15, 2, 2]], "repeat an id"),
        ([[15, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]], "entity channels hold ids 2..13"),
        ([[2, 2, 7], [10, 7, 2], [11, 7, 7], [4, 2, 2]], "avatar channel holds id 4"),
        ([[2, 12, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]], "off the"),
        ([[0, 3, 3], [10, 7, 2], [11, 7, 7], [15, 2, 2]], "empty"),
    ],
)
def test_states_that_are_no_game_state_are_refused(sim, obs, why):
    with pytest.raises(InvalidObservation, match=why):
        check_observation(obs)
    answer = in_process(sim)({"version": 1, "observation": obs, "n": 1, "max_steps": 2})
    assert not answer["ok"] and why.split()[0] in answer["error"]


def test_manual_versions_persist_and_the_same_text_is_no_new_version(encoder, tmp_path):
    state = tmp_path / "sim.json"
    s = WorldModelServer(encoder=encoder, state_path=state)
    assert s.take_env_manual(MANUAL, "newall-test:0:0") == (1, True)
    assert s.take_env_manual(MANUAL, "newall-test:0:1") == (1, False)  # the same text again
    human = list(reversed(MANUAL))
    assert s.set_manual(human, "human") == (2, True)
    assert s.take_env_manual(MANUAL[::2] + MANUAL[1:2], "newall-test:0:2") == (2, False)  # a person's manual stays
    restarted = WorldModelServer(encoder=encoder, state_path=state)
    assert (restarted.manual_version, restarted.manual, restarted.manual_source) == (2, human, "human")
    assert restarted.take_env_manual(MANUAL, "newall-test:5:0") == (3, True)  # a new game: its manual


def test_the_observational_model_ignores_the_manual_and_emma_does_not(encoder):
    request = {"observation": OBS, "actions": [[1, 1, 3, 3]], "max_steps": 4, "seed": 5}
    for kind, differs in (("emma", True), ("observational", False)):
        s = WorldModelServer(SHIPPED[kind], encoder=encoder)
        s.set_manual(MANUAL)
        before = s.handle(request)["trajectories"][0]
        s.set_manual(list(reversed(MANUAL[1:])) + ["the queen is the goal and never moves."])
        after = s.handle(request)["trajectories"][0]
        assert (before["confidence"] != after["confidence"]) == differs, kind


def plan_dict(rewards: list[float], death_share: float, ret: float | None = None) -> dict:
    n = len(rewards)
    return {
        "review_id": "newall-test:0:0",
        "plan_id": 1,
        "start_step": 0,
        "actions": [3] * n,
        "observations": [OBS] * (n + 1),
        "rewards": rewards,
        "imagined_return": sum(rewards) if ret is None else ret,
        "futures": {"k": 8, "death_share": death_share},
    }


def test_the_scripted_reviewer_never_approves_a_plan_that_dies():
    game = GameSession("newall-test", 0).env.spec
    for teach in ("online_il", "corrections", "none"):
        reviewer = ScriptedReviewer(game, teach=teach)
        decisions = [reviewer.review({**plan_dict([0.0, -1.0], 0.0), "plan_id": i})["decision"] for i in range(1, 30)]
        assert "approve" not in decisions and decisions[-1] == "abort"
        assert (decisions[0] == "imitate") == (teach == "online_il")
        # "none" gives no labels and no corrections: what the agent learns, it learns from the manual.
        assert ("corrections" in decisions) == (teach != "none"), (teach, decisions)
    reviewer = ScriptedReviewer(game)
    assert reviewer.review(plan_dict([0.5, 1.0], 0.0))["decision"] == "approve"
    assert reviewer.review(plan_dict([0.5, 1.0], 0.9))["decision"] != "approve"  # most futures die


class LoopHarness:
    """A review loop on the real game and an in-process world-model server; feedback from the test."""

    def __init__(self, sim: WorldModelServer, budget: Budget, step=None) -> None:
        self.session = GameSession("newall-test", 0)
        self.sim = sim
        self.plans: list[dict] = []
        self.requests: list[dict] = []
        self.reports: list[dict] = []
        self.progress: list[dict] = []
        self.changed = threading.Condition()
        ports = Ports(
            self._add("plan", self.plans),
            self._add("label_request", self.requests),
            self._add("execution_report", self.reports),
            lambda p: self.session.reset(p["seed"]),
            step or (lambda p: self.session.step(p["action"])),
            log=lambda s: None,
            publish_progress=self._add("progress", self.progress),
        )
        teaching = Teaching(rounds=budget.iterations, episodes=budget.episodes, grad_steps=budget.grad_steps)
        config = ReviewConfig(futures=2, budget=budget, teaching=teaching, label_timeout=30, max_rereviews=0)
        self.ledger = Ledger(tempfile.mktemp(suffix=".sqlite"))
        self.loop = ReviewLoop(
            lambda: load_policy(SHIPPED_POLICY),
            sim.encoder,
            ServiceImaginer(in_process(sim)),
            ports,
            self.ledger,
            config,
        )

    def start(self) -> dict:
        """Episode 0 of the game, with its own manual in the world-model server, handed to the
        review loop (which then makes its first plan); returns the episode's first state."""
        state = self.session.reset(0)
        self.sim.take_env_manual(self.session.manual()["descriptions"], state["episode_id"])
        self.loop.on_status(self.sim.status())
        self.loop.on_state(state)
        return state

    def _add(self, kind: str, box: list):
        def publish(payload: dict) -> None:
            messages.validate(kind, {"version": 1, **payload})  # what a node would send
            with self.changed:
                box.append(payload)
                self.changed.notify_all()

        return publish

    def wait(self, box: list, n: int, timeout: float = 120) -> dict:
        with self.changed:
            assert self.changed.wait_for(lambda: len(box) >= n, timeout), f"waited for {n}, have {len(box)}"
            return box[n - 1]


@pytest.mark.parametrize("human_texts", [False, True])
def test_the_scripted_reviewer_speaks_first_with_the_true_manual_in_other_words(human_texts):
    from pathlib import Path

    from lwm_models.text import DescriptionPools
    from lwm_models.text.parser import parse_description

    texts = Path(__file__).resolve().parents[2] / "shared" / "data" / "messenger-texts"
    if human_texts and not texts.is_dir():
        pytest.skip("no human-written descriptions beside the repo")
    pools = (
        DescriptionPools.from_files([texts / "text_train.json", texts / "text_val.json"])
        if human_texts
        else DescriptionPools.generated()
    )
    session = GameSession("newall-test", 3, pools)
    session.reset(5)
    current = session.manual()["descriptions"]
    reviewer = ScriptedReviewer(session.env.spec, language=True)
    plan = {**plan_dict([0.0, 1.0], 0.0), "review_id": "newall-test:3:5", "manual": current}
    assert reviewer.wants_to_speak(plan) and not reviewer.wants_to_speak(plan)  # once per review
    assert ScriptedReviewer(session.env.spec).wants_to_speak(plan) is False  # only when asked to
    manual = reviewer.reworded_manual(pools, "newall-test", current, seed=5)
    assert sorted(manual) != sorted(current)
    assert manual == reviewer.reworded_manual(pools, "newall-test", current, seed=5)  # seeded
    truth = {t[0]: t for t in session.env.spec.triples}
    if not human_texts:  # the generator's descriptions parse exactly: each is a true triple
        parsed = [parse_description(d) for d in manual]
        assert sorted(parsed) == sorted(truth.values())
    else:  # every description is one of the pool's texts for one of the game's triples
        for d in manual:
            assert any(d in pools.pool("newall-test", t) for t in truth.values())


def test_review_loop_manual_labels_and_closed_loop_execution(encoder):
    sim = WorldModelServer(encoder=encoder)
    h = LoopHarness(sim, Budget(iterations=1, episodes=2, grad_steps=2))
    state = h.start()
    first = h.wait(h.plans, 1)
    assert first["manual_version"] == 1 and first["reason"] == "start"
    # Before the plan, the agent taught itself from the manual, and said so round by round: first
    # that it starts, then what the world model read (round 0, roles), then each round.
    assert [(g["round"], g["done"]) for g in h.progress] == [(0, False), (0, False), (1, False), (1, True)]
    assert "roles" not in h.progress[0] and h.progress[1]["roles"] == h.progress[-1]["roles"]
    assert all("movement" in entry for entry in h.progress[1]["roles"])
    assert h.progress[-1]["manual_version"] == 1 and len(h.progress[-1]["roles"]) == 3
    assert first["roles"] == h.progress[-1]["roles"]

    # Language feedback reaches the plan under review: a new version re-plans under it.
    sim.set_manual(MANUAL, "human")
    h.loop.on_status(sim.status())
    second = h.wait(h.plans, 2)
    assert second["manual_version"] == 2 and second["reason"] == "manual" and second["manual"] == MANUAL

    with pytest.raises(FeedbackError, match="not under review"):
        h.loop.on_feedback({"review_id": first["review_id"], "plan_id": 1, "decision": "reject"})

    # Online imitation: labels are checked against the request, and bad ones change nothing.
    h.loop.on_feedback({"review_id": second["review_id"], "plan_id": 2, "decision": "imitate"})
    request = h.wait(h.requests, 1)
    n = len(request["observations"])
    base = {"review_id": request["review_id"], "request_id": request["request_id"]}
    for bad, why in [
        ({"states": [0, 1], "actions": [3]}, "one action per state"),
        ({"states": [n], "actions": [3]}, "never shown"),
        ({**base, "request_id": 7, "states": [0], "actions": [3]}, "no label request 7"),
        ({"states": [0, 0], "actions": [3, 3]}, "twice"),
    ]:
        with pytest.raises(FeedbackError, match=why):
            h.loop.on_labels({**base, **bad})
    assert len(h.plans) == 2
    h.loop.on_labels({**base, "states": list(range(n)), "actions": [3] * n})
    third = h.wait(h.plans, 3)
    assert third["reason"] == "imitation" and third["learning"]["labelled"] == n

    # Approval: the policy acts in the real game from real observations, and reports.
    h.loop.on_feedback({"review_id": third["review_id"], "plan_id": 3, "decision": "approve"})
    report = h.wait(h.reports, 1)
    assert report["outcome"] in ("won", "died", "time_limit") and report["plans"] == [3]
    assert len(report["observations"]) == report["steps"] + 1 and report["observations"][0] == state["observation"]
    kinds = [r["kind"] for r in h.ledger.history()]
    assert kinds.count("label_request") == kinds.count("labels") == 1 and kinds[-1] == "report"
    h.loop.close()


def test_a_request_that_failed_is_an_error_not_a_retry(sim):
    imaginer = ServiceImaginer(in_process(sim), retry_for=0.1)
    with pytest.raises(ImagineError, match="repeat an id"):
        bad = np.array([[2, 2, 7], [2, 7, 2], [11, 7, 7], [15, 2, 2]])
        imaginer.rollout(bad, lambda o, i, t: np.zeros(len(i), dtype=int), max_steps=2)


def test_a_stop_ends_the_execution_before_the_agent_s_next_move(encoder):
    """The real game's first step waits until the reviewer has said stop: the agent then makes no
    further move, and the report says it was stopped, within 2 s."""
    sim = WorldModelServer(encoder=encoder)
    entered, release = threading.Event(), threading.Event()
    h = None

    def gated_step(p):
        if h.session.env.t == 0:
            entered.set()
            assert release.wait(60)
        return h.session.step(p["action"])

    h = LoopHarness(sim, Budget(iterations=1, episodes=2, grad_steps=2), step=gated_step)
    h.start()
    plan = h.wait(h.plans, 1)
    base = {"review_id": plan["review_id"], "plan_id": plan["plan_id"]}
    with pytest.raises(FeedbackError, match="nothing under way to stop"):
        h.loop.on_feedback({**base, "decision": "stop"})
    h.loop.on_feedback({**base, "decision": "approve"})
    assert entered.wait(60), "the execution never stepped the game"
    said = h.loop.on_feedback({**base, "decision": "stop"})
    asked = time.monotonic()
    release.set()
    report = h.wait(h.reports, 1)
    assert time.monotonic() - asked < 2.0
    assert "stops playing" in said and report["outcome"] == "stopped"
    assert report["steps"] == h.session.env.t == 1 and len(report["observations"]) == 2
    answers = [r["payload"]["decision"] for r in h.ledger.history() if r["kind"] == "feedback"]
    assert answers == ["approve", "stop"] and h.ledger.history()[-1]["kind"] == "report"
    with pytest.raises(FeedbackError, match="is over"):
        h.loop.on_feedback({**base, "plan_id": 9, "decision": "reject"})
    h.loop.close()


def test_an_answer_re_plans_and_teaches_again_only_when_it_changes_what_the_agent_acts_on(encoder):
    """A person's answer (the same words, a fact stated): one that confirms the roles and movements
    the agent acts on re-plans at once, without teaching itself again; one that contradicts them
    makes the agent learn again under the corrected reading, which the next plan says."""
    sim = WorldModelServer(encoder=encoder)
    h = LoopHarness(sim, Budget(iterations=1, episodes=2, grad_steps=2))
    h.start()
    first = h.wait(h.plans, 1)
    words = h.session.manual()["descriptions"]
    taught = len(h.progress)
    entity = first["roles"][0]
    confirm = {"entity": entity["identity"], "field": "role", "value": entity["role"]}
    sim.set_manual(words, "human", facts=[confirm])
    h.loop.on_status(sim.status())
    second = h.wait(h.plans, 2)
    assert second["reason"] == "manual" and second["facts"] == [confirm] and len(h.progress) == taught
    assert next(e for e in second["roles"] if e["identity"] == entity["identity"])["p"] == 1.0
    other = next(r for r in ("enemy", "message", "goal") if r != entity["role"])
    contradict = {"entity": entity["identity"], "field": "role", "value": other}
    sim.set_manual(words, "human", facts=[contradict])
    h.loop.on_status(sim.status())
    third = h.wait(h.plans, 3)
    assert len(h.progress) > taught  # it learnt again under the corrected reading
    assert next(e for e in third["roles"] if e["identity"] == entity["identity"])["role"] == other
    h.loop.close()


def test_an_older_manual_delivered_again_after_a_restart_is_no_new_version(encoder, tmp_path):
    """Manual A (signed first), then B (signed later, another publisher): a restarted server that
    gets A again (latched) knows it is older than the one in force, and B stays, as do its facts."""
    state = tmp_path / "sim.json"
    s = WorldModelServer(encoder=encoder, state_path=state)
    s.take_env_manual(MANUAL, "newall-test:0:0")
    a, b = list(reversed(MANUAL)), MANUAL[1:] + MANUAL[:1]
    assert s.set_manual(a, "human", signed_at=100.0) == (2, True)
    assert s.set_manual(b, "human", signed_at=200.0) == (3, True)
    restarted = WorldModelServer(encoder=encoder, state_path=state)
    assert restarted.older(100.0) == 3 and restarted.older(300.0) is None
    assert (restarted.manual_version, restarted.manual) == (3, b)
    restarted.take_env_manual(MANUAL, "newall-test:5:0")  # a new game's own manual keeps the floor
    assert restarted.older(100.0) == 4


def test_a_reject_that_changes_nothing_says_so(encoder):
    """A reject alone changes nothing the agent has learnt: a plan imagined after it that makes the
    rejected plan's moves again carries `repeats` (the person is told what can change it), and one
    that moves otherwise does not. Ten rejects: with these seeds some plans repeat and some do not."""
    sim = WorldModelServer(encoder=encoder)
    h = LoopHarness(sim, Budget(iterations=1, episodes=2, grad_steps=2))
    h.start()
    plans = [h.wait(h.plans, 1)]
    for k in range(2, 12):
        h.loop.on_feedback({"review_id": plans[-1]["review_id"], "plan_id": plans[-1]["plan_id"], "decision": "reject"})
        plans.append(h.wait(h.plans, k))
    for rejected, new in zip(plans, plans[1:]):
        assert new["reason"] == "reject"
        assert new.get("repeats") == (rejected["plan_id"] if new["actions"] == rejected["actions"] else None)
        messages.validate("plan", {"version": messages.version("plan"), **new})
    assert any("repeats" in p for p in plans[1:]), "every reject changed the plan: nothing here was tested"
    h.loop.close()


def _weights(agent) -> dict:
    return {k: v.clone() for k, v in agent.policy.state_dict().items()}


def _same(a: dict, b: dict) -> bool:
    return all(torch.equal(a[k], b[k]) for k in a)


def test_undo_takes_back_the_newest_learning_and_returns_the_policy_to_what_it_was(encoder):
    """Two corrections, then undo twice: each undo returns the policy, its pinned corrections and
    the learning counts to what they were before the correction it takes back (the very weights),
    re-plans, and a third undo is refused in plain words. A manual change is the world-model
    server's to take back: the planner's undo refuses it and says how."""
    sim = WorldModelServer(encoder=encoder)
    h = LoopHarness(sim, Budget(iterations=1, episodes=2, grad_steps=2))
    h.start()
    plan = h.wait(h.plans, 1)
    agent = h.loop.review.agent
    before = [_weights(agent)]
    for k, step in ((2, 1), (3, 2)):
        fix = [{"step": step, "action": 4}]
        h.loop.on_feedback({**ids(plan), "decision": "corrections", "corrections": fix})
        plan = h.wait(h.plans, k)
        assert plan["reason"] == "corrections" and plan["actions"][step - 1] == 4
        before.append(_weights(agent))
    assert not _same(before[1], before[2]) and len(agent.pinned) == 2
    for k, back in ((4, before[1]), (5, before[0])):
        said = h.loop.on_feedback({**ids(plan), "decision": "undo"})
        assert said.startswith("your corrections (on plan ") and "taken back" in said, said
        plan = h.wait(h.plans, k)
        assert plan["reason"] == "undo" and _same(_weights(agent), back)
        messages.validate("plan", {"version": messages.version("plan"), **plan})
    assert not agent.pinned and plan["learning"]["corrections"] == 0
    with pytest.raises(FeedbackError, match="nothing to take back"):
        h.loop.on_feedback({**ids(plan), "decision": "undo"})

    sim.set_manual(MANUAL, "human")
    h.loop.on_status(sim.status())
    plan = h.wait(h.plans, 6)
    with pytest.raises(FeedbackError, match=r"your newest change is manual v2.*sending the manual before it again"):
        h.loop.on_feedback({**ids(plan), "decision": "undo"})
    h.loop.close()


def ids(plan: dict) -> dict:
    return {"review_id": plan["review_id"], "plan_id": plan["plan_id"]}

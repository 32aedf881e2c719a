"""The plan-review agent: plans, feedback, rejected feedback, learning in imagination."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from lwm_models.agent.agent import Correction, FeedbackError, PlanReviewAgent
from lwm_models.agent.expert import expert_actions, role_ids
from lwm_models.agent.learning import evaluate_real, expert_labeller
from lwm_models.agent.policy import EmmaPolicy
from lwm_models.data.splits import load_split
from lwm_models.messenger import rollout
from lwm_models.messenger.engine import BatchedMessenger
from lwm_models.world.frozen_text import FrozenTextEncoder
from lwm_models.world.manual import manual_batch
from lwm_models.world.registry import PRESETS, build_model

MANUAL = [
    "the plane is the deadly enemy and it chases you.",
    "the ball has the secret message and runs away from you.",
    "the robot is the goal and never moves.",
]


@pytest.fixture(scope="module")
def agent_parts():
    torch.manual_seed(0)
    game = load_split("newall-test")[0]
    engine = BatchedMessenger()
    engine.reset([game], [0])
    return game, engine.compact_observation()[0], FrozenTextEncoder()


def make_agent(agent_parts) -> PlanReviewAgent:
    game, first, encoder = agent_parts
    torch.manual_seed(0)
    world = build_model("emma", PRESETS["tiny"]).eval()
    return PlanReviewAgent(world, "emma", EmmaPolicy(), encoder, first, list(MANUAL), max_steps=6)


def test_expert_reproduces_go_to_goal():
    games = load_split("train")[:20]
    ro = rollout(games, np.arange(20), np.full(20, 4))
    for i, g in enumerate(games):
        for t in range(1, int(ro.lengths[i])):
            assert expert_actions(ro.observations[i, t - 1][None], role_ids(g), t, i)[0] == ro.actions[i, t]


def test_plan_and_manual_feedback(agent_parts):
    agent = make_agent(agent_parts)
    plan = agent.make_plan(seed=1)
    assert plan.plan_id == 1 and plan.manual_version == 1
    assert len(plan.observations) == len(plan.actions) + 1 and len(plan.confidence) == len(plan.actions)
    assert plan.observations[0] == agent_parts[1].tolist()
    assert agent.set_manual(list(reversed(MANUAL))) == 2
    assert agent.make_plan().manual_version == 2


@pytest.mark.parametrize(
    "feedback",
    [
        lambda a: a.set_manual(MANUAL[:2]),
        lambda a: a.set_manual(["", "x", "y"]),
        lambda a: a.set_manual("one string"),
        lambda a: a.correct([Correction(step=99, action=1)]),
        lambda a: a.correct([Correction(step=1, action=7)]),
        lambda a: a.correct([Correction(step=0, action=1)]),
    ],
)
def test_rejected_feedback_changes_nothing(agent_parts, feedback):
    agent = make_agent(agent_parts)
    agent.make_plan()
    before = agent.snapshot()
    with pytest.raises(FeedbackError):
        feedback(agent)
    after = agent.snapshot()
    assert before["manual"] == after["manual"] and before["manual_version"] == after["manual_version"]
    assert before["plan"] == after["plan"] and before["labelled"] == after["labelled"]
    for k, v in before["policy"].items():
        assert torch.equal(v, after["policy"][k])


def test_corrections_teach_the_policy(agent_parts):
    agent = make_agent(agent_parts)
    plan = agent.make_plan()
    wanted = (plan.actions[0] + 1) % 5
    agent.correct([Correction(step=1, action=wanted)], updates=60)
    assert agent.make_plan().actions[0] == wanted


def test_online_imitation_and_real_evaluation(agent_parts):
    game, first, encoder = agent_parts
    agent = make_agent(agent_parts)
    losses = agent.imitate(expert_labeller(game), updates=3, episodes=4)
    assert len(losses) == 3 and all(np.isfinite(losses))
    result = evaluate_real(agent.policy, game, manual_batch("emma", MANUAL, encoder), episodes=48)
    assert result.returns.shape == (48,) and -1.0 <= result.mean <= 1.5
    lo, hi = result.interval()
    assert lo <= result.mean <= hi


@pytest.mark.parametrize("setting", ["online_il", "filtered_bc", "warm_start"])
def test_table3_game(agent_parts, setting):
    from lwm_models.agent.table3 import Budget, run_game, summarize

    game, _, encoder = agent_parts
    torch.manual_seed(0)
    world = build_model("emma", PRESETS["tiny"]).eval()
    result = run_game(
        setting,
        world,
        "emma",
        EmmaPolicy(),
        game,
        MANUAL,
        encoder,
        Budget(updates=2, episodes=3, filtered_plans=4, eval_episodes=24),
    )
    assert -1.0 <= result["return"] <= 1.5 and result["wins"] + result["deaths"] <= 24
    s = summarize([result["return"], 0.5])
    assert s["ci95"][0] <= s["mean"] <= s["ci95"][1] and s["games"] == 2
    with pytest.raises(ValueError):
        run_game("dagger", world, "emma", EmmaPolicy(), game, MANUAL, encoder, Budget())

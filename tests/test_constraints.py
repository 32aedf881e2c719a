"""Decoding constraints (lwm_models.world.constraints): the rules allow every transition the real
game makes, and imagination under them with the shipped EMMA-LWM never does what the game cannot."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from game_fixtures import OBS, random_games, shipped_server

from lwm_models.messenger import POLICIES, rollout
from lwm_models.messenger.constants import AVATAR_WITH_MESSAGE, DEFAULT_MAX_STEPS
from lwm_models.world.constraints import StepRules, rule_breaks
from lwm_models.world.evaluate import consistency_counts
from lwm_models.world.imagine import imagine
from lwm_models.world.model_server import serve_json
from lwm_models.world.tokens import obs_to_tokens, reward_label


def test_the_rules_allow_every_transition_of_the_real_game():
    n = 1500
    games = random_games(n, seed=3)
    ro = rollout(games, np.arange(n) * 31 + 5, np.arange(n) % len(POLICIES))
    # Every kind of event is in the sample, or the test would prove little.
    assert {-1.0, 0.5, 1.0} <= set(np.unique(ro.rewards).tolist())
    avatar = ro.observations[:, :, 3, 0]
    assert (avatar == AVATAR_WITH_MESSAGE).any() and ((avatar == 0) & (np.arange(33) < ro.lengths[:, None])).any()
    assert (ro.lengths == DEFAULT_MAX_STEPS + 1).any()  # episodes that reach the time limit
    breaks, steps = rule_breaks(ro.observations, ro.actions, ro.rewards, ro.dones, ro.lengths)
    assert steps == int((ro.lengths - 1).sum()) and breaks.tolist() == [0] * 14


def test_the_rules_refuse_what_the_game_cannot_do():
    # Avatar at (2, 2) moving right to (2, 3); entity channels: a plane at (2, 7) (far), a ball at
    # (2, 4) (in reach), a robot at (7, 7).
    obs = np.array([[2, 2, 7], [10, 2, 4], [11, 7, 7], [15, 2, 2]])
    prev, act = torch.tensor(obs_to_tokens(obs))[None], torch.tensor([3])
    rules = StepRules(prev, act)

    def tokens(channels):
        """The sampled tokens of these channels (the rest padded, to be cut off by the caller)."""
        padded = np.array(channels + [[0, 0, 0]] * (4 - len(channels)))
        return list(torch.tensor(obs_to_tokens(padded))[:, None])

    ids = rules.allowed(0, [])[0]
    assert ids.nonzero().flatten().tolist() == [2]  # the far plane neither changes nor vanishes
    assert rules.allowed(3, tokens([[2, 2, 7]])[:3])[0].nonzero().flatten().tolist() == [0, 10]  # the ball may go
    rows = rules.allowed(1, tokens([[2, 2, 7]])[:1])[0].nonzero().flatten() - 17
    assert rows.tolist() == [1, 2, 3]
    cols = rules.allowed(2, tokens([[2, 3, 7]])[:2])[0].nonzero().flatten() - 27
    assert cols.tolist() == [7]  # a row move leaves the column as it was
    # The ball vanished: the avatar picked up the message (16) or died on it (0), never stays 15.
    now = tokens([[2, 2, 7], [0, 0, 0], [11, 7, 7]])
    assert rules.allowed(9, now[:9])[0].nonzero().flatten().tolist() == [0, 16]
    # The avatar lands exactly where its action takes it.
    now = tokens([[2, 2, 7], [10, 2, 4], [11, 7, 7], [15, 2, 3]])
    assert rules.allowed(9, now[:9])[0].nonzero().flatten().tolist() == [15]  # nothing overlaps it: no death
    assert rules.allowed(10, now[:10])[0].nonzero().flatten().tolist() == [17 + 2]
    assert rules.allowed(11, now[:11])[0].nonzero().flatten().tolist() == [27 + 3]
    # Nothing changed: reward 0 and no end.
    assert rules.allowed(12, now)[0].nonzero().flatten().tolist() == [int(reward_label(0.0))]
    assert rules.allowed(13, now + [torch.tensor([2])])[0].nonzero().flatten().tolist() == [0]


@pytest.fixture(scope="module")
def sim():
    return shipped_server()


def test_constrained_imagination_is_consistent_and_raw_rows_are_untouched(sim):
    n, steps = 48, 32
    rng = np.random.default_rng(0)
    actions = rng.integers(5, size=(n, steps))
    first = np.array(OBS, dtype=np.uint8)
    im = imagine(sim.model, sim._batch, first, n=n, actions=actions, seed=4, constrained=True)
    counts = consistency_counts(im.observations, im.rewards, im.lengths)
    assert counts["transitions"] > 300
    assert counts["identity_changes"] == counts["avatar_jumps"] == counts["vanished_without_reward"] == 0
    breaks, _ = rule_breaks(im.observations, im.actions, im.rewards, im.dones, im.lengths)
    assert breaks.tolist() == [0] * 14
    # The same steps sampled raw break rules: the model alone does not keep them.
    raw = imagine(sim.model, sim._batch, first, n=n, actions=actions, seed=4)
    assert rule_breaks(raw.observations, raw.actions, raw.rewards, raw.dones, raw.lengths)[0].sum() > 0
    # The model still decides: the trajectories differ, and some end before the time limit.
    assert len({im.observations[i, 5].tobytes() for i in range(n)}) > 1
    assert (im.lengths < steps + 1).any()
    # Confidence is the model's own probability, not the renormalised one: below 1 somewhere.
    assert (im.confidence()[:, 1:][im.confidence()[:, 1:] < 1]).size > 0

    # Raw rows sharing a batch with constrained ones sample what they sample alone.
    alone = sim.imagine({"observation": OBS, "actions": actions[:3].tolist(), "max_steps": 8, "seed": 9})
    from lwm_models.world.continuous import ContinuousBatch

    raw, ruled = sim.one_shot({**_req(actions[:3], 9)}), sim.one_shot({**_req(actions[3:6], 10), "constrained": True})
    batch = ContinuousBatch(sim.model)
    batch.admit(ruled)
    batch.admit(raw)
    while batch:
        batch.step()
    assert sim.answer(raw)["trajectories"] == alone["trajectories"]


def _req(actions: np.ndarray, seed: int) -> dict:
    return {"observation": OBS, "actions": actions.tolist(), "max_steps": 8, "seed": seed}


def test_the_service_takes_constrained_requests(sim):
    request = {"version": 1, "observation": OBS, "n": 16, "max_steps": 20, "seed": 1, "constrained": True}
    request["actions"] = [[(i + k) % 5 for k in range(20)] for i in range(16)]
    answer = json.loads(serve_json(sim, json.dumps(request))[0])
    assert answer["ok"], answer
    trajectories = answer["trajectories"]
    obs = np.zeros((16, 21, 4, 3), dtype=np.uint8)
    rewards = np.zeros((16, 21), dtype=np.float32)
    lengths = np.array([len(t["observations"]) for t in trajectories])
    for i, t in enumerate(trajectories):
        obs[i, : lengths[i]] = t["observations"]
        rewards[i, 1 : lengths[i]] = t["rewards"]
    counts = consistency_counts(obs, rewards, lengths)
    assert counts["identity_changes"] == counts["avatar_jumps"] == counts["vanished_without_reward"] == 0
    bad = json.loads(serve_json(sim, json.dumps({**request, "constrained": "yes"}))[0])
    assert not bad["ok"] and "constrained" in bad["error"]


def test_impossible_mass_sees_how_much_a_model_learnt_the_rules(tmp_path, sim):
    """Teacher-forced mass on forbidden tokens: the shipped model's is a fraction of an untrained
    copy's, and the groups add up to the whole."""
    from lwm_models.data.dataset import generate_dataset
    from lwm_models.text import DescriptionPools
    from lwm_models.world.evaluate import IMPOSSIBLE_GROUPS, impossible_mass
    from lwm_models.world.registry import build_model
    from lwm_models.world.training_data import SplitTokens

    generate_dataset(tmp_path, DescriptionPools.generated(), max_games=12, train_episodes_per_game=1)
    shipped = sim.model
    data = SplitTokens(tmp_path, "newall-test", shipped.frozen_text_encoder(), shipped.route)
    trained = impossible_mass(shipped, data, episodes=40)
    torch.manual_seed(0)
    untrained = impossible_mass(build_model("emma", shipped.config), data, episodes=40)
    assert 0 < trained["per_step"] < 0.25 * untrained["per_step"], (trained, untrained)
    assert untrained["per_step"] > 1.0  # most of a step's tokens break a rule when guessed
    for m in (trained, untrained):
        assert sum(m[name] for name in IMPOSSIBLE_GROUPS) == pytest.approx(m["per_step"])
        assert len(m["per_slot"]) == 14


def test_the_planner_can_show_constrained_plans_and_learn_from_raw_ones(sim):
    """Through the service: an imaginer constrained by default (plans shown to people) imagines
    nothing impossible, and a rollout asked raw (learning rounds) is the model's own samples."""
    from lwm_models.agent.imaginer import ServiceImaginer, in_process

    imaginer = ServiceImaginer(in_process(sim), constrained=True)
    rng = np.random.default_rng(2)

    def policy(obs, idx, t):
        return rng.integers(5, size=len(idx))

    start = np.array(OBS, dtype=np.uint8)
    ruled = imaginer.rollout(start, policy, n=32, seed=1)
    raw = imaginer.rollout(start, policy, n=32, seed=1, constrained=False)
    for im, broken in ((ruled, False), (raw, True)):
        breaks, steps = rule_breaks(im.observations, im.actions, im.rewards, im.dones, im.lengths)
        assert steps > 200 and (breaks.sum() > 0) == broken, breaks

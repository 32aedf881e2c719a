"""The batched engine against the single-game reference, and the behaviour policies."""

from __future__ import annotations

import numpy as np
import pytest
from game_fixtures import random_games

from lwm_models.data.splits import load_split
from lwm_models.errors import GameStateError, InvalidActionError, ShapeError
from lwm_models.messenger import (
    POLICIES,
    BatchedMessenger,
    MessengerEnv,
    compact_to_grid,
    grid_to_compact,
    rollout,
)


def test_batched_engine_replays_the_single_game_reference_exactly():
    games = random_games(250, seed=1)
    seeds = np.arange(250) * 7919 + 11
    policies = np.arange(250) % len(POLICIES)
    ro = rollout(games, seeds, policies)
    assert set(np.unique(ro.rewards)) <= {-1.0, 0.0, 0.5, 1.0}
    for i, game in enumerate(games):
        env = MessengerEnv(game)
        obs, info = env.reset(seed=int(seeds[i]))
        assert info["start"] == ro.starts[i]
        np.testing.assert_array_equal(obs, compact_to_grid(ro.observations[i, 0]))
        for t in range(1, int(ro.lengths[i])):
            obs, r, term, trunc, _ = env.step(int(ro.actions[i, t]))
            np.testing.assert_array_equal(obs, compact_to_grid(ro.observations[i, t]), err_msg=f"game {i} t {t}")
            assert r == ro.rewards[i, t] and (term or trunc) == ro.dones[i, t]
        assert env.done, f"game {i}: the reference did not end where the batch did"


def test_an_episode_does_not_depend_on_its_batch():
    games = random_games(40, seed=2)
    seeds = np.arange(40) + 100
    policies = np.arange(40) % 5
    whole = rollout(games, seeds, policies)
    part = rollout(games[10:13], seeds[10:13], policies[10:13])
    np.testing.assert_array_equal(whole.observations[10:13], part.observations)
    np.testing.assert_array_equal(whole.actions[10:13], part.actions)


def test_policy_returns_match_the_reference_figures():
    # The original implementation's returns (docs/game.md, "Behaviour policies"; 100 games):
    # go_to_goal ~ +1.2..1.3, get_message +0.56, survive +0.09, random -0.47, suicide -0.98.
    # Tolerances cover sampling noise of 3,000 episodes.
    games = load_split("train")
    rng = np.random.default_rng(0)
    n = 3000
    chosen = [games[i] for i in rng.integers(len(games), size=n)]
    expected = {
        "random": (-0.47, 0.1),
        "suicide": (-0.98, 0.05),
        "survive": (0.09, 0.12),
        "get_message": (0.56, 0.12),
        "go_to_goal": (1.25, 0.1),
    }
    for p, name in enumerate(POLICIES):
        ro = rollout(chosen, np.arange(n) + 10_000 * p, np.full(n, p))
        mean, tol = expected[name]
        assert abs(ro.returns.mean() - mean) <= tol, (name, float(ro.returns.mean()))


def test_compact_and_grid_round_trip():
    games = random_games(20, seed=3)
    ro = rollout(games, np.arange(20), np.arange(20) % 5)
    grids = compact_to_grid(ro.observations)
    assert grids.shape == (20, 33, 10, 10, 4)
    np.testing.assert_array_equal(grid_to_compact(grids), ro.observations)


def test_shape_errors():
    with pytest.raises(ShapeError):
        compact_to_grid(np.zeros((4, 2), dtype=np.uint8))
    with pytest.raises(ShapeError):
        grid_to_compact(np.zeros((10, 10, 3), dtype=np.uint8))
    two = np.zeros((10, 10, 4), dtype=np.uint8)
    two[0, 0, 0] = two[1, 1, 0] = 2
    with pytest.raises(ShapeError):
        grid_to_compact(two)


def test_batched_bad_input():
    engine = BatchedMessenger()
    with pytest.raises(GameStateError):
        engine.step(np.zeros(1, dtype=np.int64))
    games = random_games(3, seed=4)
    with pytest.raises(ShapeError):
        engine.reset(games, [1, 2])
    engine.reset(games, [1, 2, 3])
    for bad in (np.array([0, 1, 5]), np.array([0, -1, 2]), np.array([0, 1]), np.array([0.0, 1.0, 2.0])):
        with pytest.raises(InvalidActionError):
            engine.step(bad)
    with pytest.raises(ShapeError):
        engine.reset(games, [1, 2, 3], starts=[0, 1, 24])


def test_finished_games_stay_frozen():
    games = random_games(8, seed=5)
    engine = BatchedMessenger(max_steps=2)
    engine.reset(games, np.arange(8))
    engine.step(np.full(8, 4))
    engine.step(np.full(8, 4))
    assert engine.done.all()
    before = engine.compact_observation()
    r, term, trunc, running = engine.step(np.full(8, 0))
    assert not running.any() and not r.any() and not term.any() and not trunc.any()
    np.testing.assert_array_equal(before, engine.compact_observation())

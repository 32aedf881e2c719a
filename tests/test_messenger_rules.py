"""Scenario tests that pin each rule of Messenger stage 2 (docs/game.md, "The game") with
hand-worked half-cell positions. Positions are (row, col) in half-cells; cell = half // 2."""

from __future__ import annotations

import numpy as np
import pytest

from lwm_models.errors import GameStateError, InvalidActionError, InvalidSpecError
from lwm_models.messenger import BatchedMessenger, GameSpec, MessengerEnv
from lwm_models.messenger.constants import (
    AVATAR_CHANNEL,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    IDENTITIES,
    STARTS,
)
from lwm_models.text import DescriptionPools

UP, DOWN, LEFT, RIGHT, STAY = range(5)
ENEMY, MESSAGE, GOAL = range(3)


def make_env(enemy="chaser", message="immovable", goal="immovable", max_steps=32, seed=0, pools=None) -> MessengerEnv:
    spec = GameSpec.from_triples([("dog", enemy, "enemy"), ("queen", message, "message"), ("ball", goal, "goal")])
    env = MessengerEnv(spec, pools=pools, max_steps=max_steps)
    env.reset(seed=seed)
    return env


def place(env: MessengerEnv, avatar, enemy=(18, 18), message=(18, 0), goal=(0, 18)) -> None:
    """Put the sprites at the given half-cell positions (None removes the message)."""
    env.avatar = avatar
    env.positions = [enemy, message, goal]


def cell_of(obs: np.ndarray, identity: str) -> tuple[int, int] | None:
    hits = np.argwhere((obs[..., :3] == IDENTITIES[identity]).any(-1))
    return tuple(int(x) for x in hits[0]) if len(hits) else None


def avatar_cell(obs: np.ndarray):
    hits = np.argwhere(obs[..., AVATAR_CHANNEL] > 0)
    return (tuple(int(x) for x in hits[0]), int(obs[..., AVATAR_CHANNEL].max())) if len(hits) else None


def test_chaser_at_odd_offset_kills_from_the_neighbouring_cell():
    env = make_env(enemy="chaser")
    place(env, avatar=(6, 8), enemy=(6, 5))
    obs, r, term, _, _ = env.step(STAY)  # enemy to (6, 6): two half-cells apart, no collision
    assert (r, term) == (0.0, False)
    assert cell_of(obs, "dog") == (3, 3) and avatar_cell(obs)[0] == (3, 4)
    obs, r, term, trunc, info = env.step(STAY)  # enemy to (6, 7): shown in cell (3, 3), touches (3, 4)
    assert info["half_cell_positions"]["enemy"] == (6, 7)
    assert cell_of(obs, "dog") == (3, 3)
    assert (r, term, trunc) == (-1.0, True, False)
    assert avatar_cell(obs) is None, "the avatar channel is empty after death"


def test_odd_offset_collides_diagonally_and_not_from_the_left():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(7, 7))  # both offsets odd: diagonal neighbour below-right
    _, r, term, _, _ = env.step(STAY)
    assert (r, term) == (-1.0, True)
    env = make_env(enemy="immovable")
    place(env, avatar=(6, 4), enemy=(6, 7))  # avatar in the cell to the left of (3, 3): 3 apart
    _, r, term, _, _ = env.step(STAY)
    assert (r, term) == (0.0, False)


def enemy_after_one_step(movement: str, avatar, enemy, seeds: int) -> list:
    """Where an enemy of `movement` placed at `enemy` is after one step of an avatar that stays at
    `avatar` (half cells), for episode seeds 0..seeds-1."""
    where = []
    for seed in range(seeds):
        env = make_env(enemy=movement, seed=seed)
        place(env, avatar=avatar, enemy=enemy)
        env.step(STAY)
        where.append(env.positions[ENEMY])
    return where


def test_fleeing_entity_at_the_edge_sometimes_stays_put():
    outcomes = enemy_after_one_step("fleeing", avatar=(4, 10), enemy=(0, 10), seeds=300)
    counts = {p: outcomes.count(p) for p in set(outcomes)}
    # Up (off the board: undone), left and right increase the distance; down never does.
    assert set(counts) == {(0, 10), (0, 9), (0, 11)}
    for p in counts:
        assert 60 < counts[p] < 140, counts


def test_fleeing_entity_in_a_corner_cannot_escape():
    assert set(enemy_after_one_step("fleeing", avatar=(4, 4), enemy=(0, 0), seeds=50)) == {(0, 0)}


def test_chaser_picks_uniformly_among_decreasing_directions():
    moves = enemy_after_one_step("chaser", avatar=(8, 8), enemy=(0, 0), seeds=400)
    assert set(moves) == {(1, 0), (0, 1)}
    assert 150 < moves.count((1, 0)) < 250


def test_chaser_with_no_decreasing_direction_moves_at_random():
    # On the avatar's position no move decreases the distance: uniform over all four directions.
    moves = enemy_after_one_step("chaser", avatar=(10, 10), enemy=(10, 10), seeds=200)
    assert set(moves) == {(9, 10), (11, 10), (10, 9), (10, 11)}
    assert min(moves.count(m) for m in set(moves)) > 25


def test_entities_decide_from_the_avatar_position_before_it_moves():
    # From (6, 6) only "right" brings the chaser closer; from (8, 6), where the avatar goes,
    # "down" would too. The chaser must always go right.
    for seed in range(50):
        env = make_env(enemy="chaser", seed=seed)
        place(env, avatar=(6, 6), enemy=(6, 4))
        _, r, _, _, _ = env.step(DOWN)
        assert env.positions[ENEMY] == (6, 5)
        assert env.avatar == (8, 6) and r == 0.0


def test_display_is_the_floor_of_half_cells():
    env = make_env(enemy="chaser")
    place(env, avatar=(2, 6), enemy=(10, 6))
    obs, *_ = env.step(STAY)  # moving up: the new cell shows at once
    assert env.positions[ENEMY] == (9, 6) and cell_of(obs, "dog") == (4, 3)
    env = make_env(enemy="chaser")
    place(env, avatar=(12, 6), enemy=(2, 6))
    obs, *_ = env.step(STAY)  # moving down: still shown in the old cell
    assert env.positions[ENEMY] == (3, 6) and cell_of(obs, "dog") == (1, 3)
    obs, *_ = env.step(STAY)
    assert cell_of(obs, "dog") == (2, 3)


def test_avatar_move_off_the_board_is_undone():
    env = make_env(enemy="immovable")
    place(env, avatar=(0, 0))
    obs, *_ = env.step(UP)
    assert env.avatar == (0, 0)
    obs, *_ = env.step(LEFT)
    assert env.avatar == (0, 0)
    obs, *_ = env.step(RIGHT)
    assert env.avatar == (0, 2) and avatar_cell(obs) == ((0, 1), AVATAR_NO_MESSAGE)


def test_pick_up_then_delivery():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), message=(8, 10), goal=(8, 14))
    obs, r, term, _, info = env.step(RIGHT)
    assert (r, term) == (0.5, False)
    assert info["has_message"] and avatar_cell(obs) == ((4, 5), AVATAR_WITH_MESSAGE)
    assert cell_of(obs, "queen") is None, "the message channel empties after pick-up"
    assert env.positions[MESSAGE] is None
    obs, r, term, _, _ = env.step(RIGHT)
    assert (r, term) == (0.0, False)
    obs, r, term, trunc, _ = env.step(RIGHT)
    assert (r, term, trunc) == (1.0, True, False)
    assert avatar_cell(obs) == ((4, 7), AVATAR_WITH_MESSAGE), "a winning avatar stays on the board"
    assert cell_of(obs, "ball") is None, "the delivered-to goal leaves the board"


def test_enemy_has_priority_over_pick_up():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(8, 10), message=(8, 10))
    obs, r, term, _, info = env.step(RIGHT)
    assert (r, term) == (-1.0, True)
    assert not info["has_message"] and avatar_cell(obs) is None
    # Last frame: the overlapped message is removed too (before the avatar); the enemy stays.
    assert cell_of(obs, "queen") is None and cell_of(obs, "dog") == (4, 5)


def test_goal_without_message_kills_and_beats_the_message():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), message=(8, 10), goal=(8, 10))
    obs, r, term, _, info = env.step(RIGHT)
    assert (r, term) == (-1.0, True) and not info["has_message"]
    assert avatar_cell(obs) is None and cell_of(obs, "queen") is None
    assert cell_of(obs, "ball") == (4, 5), "the goal that killed the avatar stays"


# ----------------------------------------------------------------- what the last frame shows


def test_spec_example_death_while_overlapping_the_message_removes_it():
    # The spec's example: avatar at (10, 10) without the message, immovable message at (10, 12),
    # chaser enemy at (9, 13), action right. The chaser decides from (10, 10): down (to (10, 13))
    # and left (to (9, 12)) both bring it closer. The avatar moves to (10, 12): on the message, and
    # the enemy is at most 1 half-cell away on each axis either way, so the avatar dies.
    shown = set()
    for seed in range(20):
        env = make_env(enemy="chaser", message="immovable", seed=seed)
        place(env, avatar=(10, 10), enemy=(9, 13), message=(10, 12), goal=(0, 18))
        obs, r, term, trunc, info = env.step(RIGHT)
        assert env.positions[ENEMY] in {(10, 13), (9, 12)}
        assert (r, term, trunc) == (-1.0, True, False)
        assert not info["has_message"] and not env.alive
        assert avatar_cell(obs) is None, "the avatar channel is empty after death"
        assert cell_of(obs, "queen") is None, "the overlapped message is gone from the last frame"
        assert info["half_cell_positions"]["message"] is None
        assert cell_of(obs, "ball") == (0, 9)
        shown.add(cell_of(obs, "dog"))
    assert shown == {(5, 6), (4, 6)}  # (10, 13) shows in cell (5, 6), (9, 12) in (4, 6)


def test_death_by_goal_while_overlapping_the_message_removes_it():
    # Avatar (8, 8) -> (8, 10): on the message at (8, 10), and the goal at (9, 11) is 1 half-cell
    # away on both axes (diagonal overlap). Goal without message: death, and the message goes.
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(18, 18), message=(8, 10), goal=(9, 11))
    obs, r, term, _, info = env.step(RIGHT)
    assert (r, term) == (-1.0, True) and not info["has_message"]
    assert avatar_cell(obs) is None and cell_of(obs, "queen") is None
    assert cell_of(obs, "ball") == (4, 5) and cell_of(obs, "dog") == (9, 9)


def test_death_without_touching_the_message_leaves_every_entity_on_the_board():
    # Avatar (8, 8) -> (8, 10) onto the immovable enemy; the message at (8, 12) is 2 half-cells
    # away (no overlap), so it stays, as does the goal.
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(8, 10), message=(8, 12), goal=(0, 18))
    obs, r, term, _, _ = env.step(RIGHT)
    assert (r, term) == (-1.0, True) and avatar_cell(obs) is None
    assert cell_of(obs, "dog") == (4, 5) and cell_of(obs, "queen") == (4, 6) and cell_of(obs, "ball") == (0, 9)


def test_a_win_removes_the_goal_and_keeps_the_carrying_avatar():
    # The avatar carries the message (the message is off the board). Avatar (8, 8) -> (8, 10); the
    # immovable goal at (9, 11) overlaps diagonally (both offsets odd): reward +1, win.
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(18, 18), message=None, goal=(9, 11))
    env.has_message = True
    obs, r, term, trunc, info = env.step(RIGHT)
    assert (r, term, trunc) == (1.0, True, False) and env.won
    assert cell_of(obs, "ball") is None, "the goal is gone from the last frame of a win"
    assert info["half_cell_positions"]["goal"] is None
    assert avatar_cell(obs) == ((4, 5), AVATAR_WITH_MESSAGE)
    assert cell_of(obs, "dog") == (9, 9) and cell_of(obs, "queen") is None


def batched_copy(env: MessengerEnv) -> BatchedMessenger:
    """A one-game batched engine in exactly the state of `env` (same seed, so same draws)."""
    engine = BatchedMessenger(max_steps=env.max_steps)
    engine.reset([env.spec], [env.seed], starts=[env.start])
    engine.avatar_row[0], engine.avatar_col[0] = env.avatar
    for k, pos in enumerate(env.positions):
        engine.present[0, k] = pos is not None
        if pos is not None:
            engine.entity_row[0, k], engine.entity_col[0, k] = pos
    engine.has_message[0] = env.has_message
    engine.t = env.t
    return engine


@pytest.mark.parametrize(
    "case",
    [
        dict(avatar=(10, 10), enemy=(9, 13), message=(10, 12), goal=(0, 18)),  # the spec's example
        dict(avatar=(8, 8), enemy=(18, 18), message=(8, 10), goal=(9, 11)),  # goal death on the message
        dict(avatar=(8, 8), enemy=(8, 10), message=(8, 10), goal=(0, 18)),  # enemy death on the message
        dict(avatar=(8, 8), enemy=(8, 10), message=(8, 12), goal=(0, 18)),  # death, message untouched
        dict(avatar=(8, 8), enemy=(18, 18), message=None, goal=(9, 11), carrying=True),  # win
    ],
)
def test_batched_engine_shows_the_same_last_frame(case):
    case = dict(case)
    carrying = case.pop("carrying", False)
    for seed in range(6):
        env = make_env(enemy="chaser", seed=seed)
        place(env, **case)
        env.has_message = carrying
        engine = batched_copy(env)
        obs, r, term, trunc, _ = env.step(RIGHT)
        rewards, terminated, truncated, _ = engine.step(np.array([RIGHT]))
        np.testing.assert_array_equal(engine.observation()[0], obs)
        assert (float(rewards[0]), bool(terminated[0]), bool(truncated[0])) == (r, term, trunc)
        assert term


def test_enemy_kills_a_carrier_too():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), message=None, enemy=(8, 10))
    env.has_message = True
    _, r, term, _, _ = env.step(RIGHT)
    assert (r, term) == (-1.0, True)


def test_time_limit_is_a_parameter_and_truncates_without_penalty():
    env = make_env(enemy="immovable", max_steps=3)
    place(env, avatar=(8, 8))
    results = [env.step(STAY)[1:4] for _ in range(3)]
    assert results == [(0.0, False, False), (0.0, False, False), (0.0, False, True)]
    with pytest.raises(GameStateError):
        env.step(STAY)


def test_default_time_limit_is_32_actions():
    env = make_env(enemy="immovable")
    place(env, avatar=(8, 8), enemy=(0, 0), message=(0, 18), goal=(18, 0))
    steps = 0
    while True:
        steps += 1
        *_, trunc, _ = env.step(STAY)
        if trunc:
            break
    assert steps == 32


def test_starts_follow_the_documented_order():
    env = make_env()
    seen = set()
    for i in range(24):
        obs, info = env.reset(seed=1, options={"start": i})
        a, e, m, g = STARTS[i]
        assert avatar_cell(obs) == (a, AVATAR_NO_MESSAGE)
        assert (cell_of(obs, "dog"), cell_of(obs, "queen"), cell_of(obs, "ball")) == (e, m, g)
        seen.add(STARTS[i])
    assert len(seen) == 24
    with pytest.raises(ValueError):
        env.reset(seed=0, options={"start": 24})


def test_channel_permutation_is_random_per_episode_and_fixed_within_it():
    env = make_env(enemy="chaser")
    perms = set()
    for seed in range(60):
        obs, info = env.reset(seed=seed)
        order = info["channel_identities"]
        perms.add(tuple(order))
        for _ in range(3):
            obs, *_, info = env.step(STAY)
            if env.done:
                break
            assert info["channel_identities"] == order
            for ch, name in enumerate(order):
                if name != "queen" or env.positions[MESSAGE] is not None:
                    assert obs[..., ch].max() == IDENTITIES[name]
    assert len(perms) == 6


def test_reset_is_a_function_of_the_seed():
    env = make_env(enemy="chaser", message="fleeing")
    a = [env.reset(seed=5)[0]] + [env.step(a)[0] for a in (0, 1, 2)]
    b = [env.reset(seed=5)[0]] + [env.step(a)[0] for a in (0, 1, 2)]
    assert all((x == y).all() for x, y in zip(a, b))


def test_manual_has_three_descriptions_aligned_with_the_parse():
    env = make_env(pools=DescriptionPools.generated())
    _, info = env.reset(seed=3)
    assert len(info["manual"]) == 3 and all(isinstance(t, str) and t for t in info["manual"])
    assert sorted(map(tuple, info["parse"])) == sorted(env.spec.triples)
    # Without a source of text the game still plays, and still tells the true parse.
    _, info = make_env().reset(seed=3)
    assert info["manual"] is None and sorted(map(tuple, info["parse"])) == sorted(env.spec.triples)


@pytest.mark.parametrize("bad", [-1, 5, 2.0, "up", None, True])
def test_bad_actions_are_rejected(bad):
    env = make_env()
    with pytest.raises(InvalidActionError):
        env.step(bad)


def test_step_before_reset():
    spec = GameSpec.from_triples(
        [("dog", "chaser", "enemy"), ("queen", "fleeing", "message"), ("ball", "immovable", "goal")]
    )
    with pytest.raises(GameStateError):
        MessengerEnv(spec).step(0)


@pytest.mark.parametrize(
    "triples",
    [
        [("dog", "chaser", "enemy"), ("queen", "fleeing", "message")],
        [("dragon", "chaser", "enemy"), ("queen", "fleeing", "message"), ("ball", "immovable", "goal")],
        [("dog", "teleporting", "enemy"), ("queen", "fleeing", "message"), ("ball", "immovable", "goal")],
        [("dog", "chaser", "enemy"), ("queen", "fleeing", "enemy"), ("ball", "immovable", "goal")],
        [("dog", "chaser", "enemy"), ("dog", "fleeing", "message"), ("ball", "immovable", "goal")],
        [("dog", "chaser"), ("queen", "fleeing", "message"), ("ball", "immovable", "goal")],
        "dog",
    ],
)
def test_malformed_game_specs_are_rejected(triples):
    with pytest.raises(InvalidSpecError):
        GameSpec.from_triples(triples)

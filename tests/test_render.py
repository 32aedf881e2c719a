"""Tests of the pictures of observations (messenger/render.py) and the terminal game (cli/play.py).

Boards are checked against positions read from the observation itself, so a test fails when a
sprite is drawn in the wrong cell, not only when the drawing changes.
"""

from __future__ import annotations

import io
import re

import numpy as np
import pytest
from PIL import Image

from lwm_models.cli.play import line_key_reader, play_main, run_game, split_keys
from lwm_models.errors import ShapeError
from lwm_models.messenger import GameSpec, MessengerEnv, grid_to_compact
from lwm_models.messenger.constants import (
    AVATAR_CHANNEL,
    AVATAR_NO_MESSAGE,
    AVATAR_WITH_MESSAGE,
    DOWN,
    GRID,
    ID_TO_IDENTITY,
    IDENTITIES,
    RIGHT,
    STARTS,
)
from lwm_models.messenger.render import (
    IDENTITY_LETTERS,
    board,
    legend,
    render_ascii,
    render_png,
    render_trajectory_gif,
    render_trajectory_png,
    symbol_key,
)

ANSI = re.compile(r"\x1b\[[0-9;]*m")


class TinyPools:
    """Stands in for lwm_models.text.DescriptionPools: one plain description per triple."""

    def draw(self, split, triples, rng):
        return [f"the {ident} is the {role} and it is {mov}" for ident, mov, role in triples]


def make_env(enemy_movement: str = "immovable", max_steps: int = 32) -> MessengerEnv:
    """dog enemy, queen message, ball goal; all but (optionally) the enemy stand still, so the
    scripted games below play out the same way whatever the seed."""
    spec = GameSpec.from_triples(
        [("dog", enemy_movement, "enemy"), ("queen", "immovable", "message"), ("ball", "immovable", "goal")]
    )
    return MessengerEnv(spec, pools=TinyPools(), max_steps=max_steps)


def symbol_at(board: str, row: int, col: int) -> str:
    """The symbol of cell (row, col) on a render_ascii board: line row + 1, character 2 + 2 col."""
    return board.splitlines()[row + 1][2 + 2 * col]


def sprites(obs: np.ndarray) -> list[tuple[int, int, int]]:
    """(id, row, col) of every sprite in a grid observation."""
    return [(int(obs[r, c, ch]), int(r), int(c)) for r, c, ch in np.argwhere(obs != 0)]


# --------------------------------------------------------------------------- ascii
def test_letters_are_unique_and_cover_every_identity():
    assert set(IDENTITY_LETTERS) == set(IDENTITIES)
    letters = list(IDENTITY_LETTERS.values())
    assert len(set(letters)) == len(letters)
    assert not {"@", "&", ".", "*"} & set(letters)


@pytest.mark.parametrize("start", [0, 7, 23])
def test_ascii_board_puts_every_sprite_in_its_cell(start):
    env = make_env(enemy_movement="chaser")
    obs, _ = env.reset(seed=3, options={"start": start})
    for _ in range(3):
        obs, *_ = env.step(DOWN)
    board = render_ascii(obs)
    lines = board.splitlines()
    assert len(lines) == GRID + 2
    assert lines[0] == lines[-1] and set(lines[0]) == {"+", "-"}
    assert all(line.startswith("| ") and line.endswith(" |") for line in lines[1:-1])
    found = sprites(obs)
    assert len(found) == 4
    for sprite_id, r, c in found:
        expected = "@" if sprite_id == AVATAR_NO_MESSAGE else IDENTITY_LETTERS[ID_TO_IDENTITY[sprite_id]]
        assert symbol_at(board, r, c) == expected
    occupied = {(r, c) for _, r, c in found}
    empty = [(r, c) for r in range(GRID) for c in range(GRID) if (r, c) not in occupied]
    assert all(symbol_at(board, r, c) == "." for r, c in empty)


def test_avatar_carrying_the_message_is_drawn_as_ampersand():
    env = make_env()
    obs, _ = env.reset(seed=0, options={"start": 0})  # avatar (2, 2), message (7, 2)
    assert STARTS[0][0] == (2, 2) and STARTS[0][2] == (7, 2)
    rewards = []
    for _ in range(5):
        obs, r, term, _, _ = env.step(DOWN)
        rewards.append(r)
    assert rewards == [0.0, 0.0, 0.0, 0.0, 0.5] and not term
    assert obs[7, 2, AVATAR_CHANNEL] == AVATAR_WITH_MESSAGE
    board = render_ascii(obs)
    assert symbol_at(board, 7, 2) == "&"
    assert "@" not in board and "Q" not in board, "the message is gone once picked up"
    assert "& you, carrying the message" in legend(obs)
    assert "queen" not in legend(obs)


def test_legend_names_the_letters_present():
    env = make_env()
    obs, _ = env.reset(seed=0, options={"start": 0})
    text = legend(obs)
    for name in ("dog", "queen", "ball"):
        assert f"{IDENTITY_LETTERS[name]} {name}" in text
    assert "@ you" in text
    assert "airplane" not in text


def test_overlaps_show_the_avatar_or_a_star_and_the_legend_names_them():
    grid = np.zeros((GRID, GRID, 4), dtype=np.uint8)
    grid[1, 1, 0] = IDENTITIES["dog"]
    grid[1, 1, 1] = IDENTITIES["queen"]  # two entities, no avatar
    grid[5, 6, 2] = IDENTITIES["ball"]
    grid[5, 6, AVATAR_CHANNEL] = AVATAR_WITH_MESSAGE  # the winning frame: avatar on the goal
    board = render_ascii(grid)
    assert symbol_at(board, 1, 1) == "*"
    assert symbol_at(board, 5, 6) == "&"
    text = legend(grid)
    assert "* dog+queen" in text
    assert "(on ball)" in text


def test_a_legend_for_later_boards_names_both_avatar_symbols_and_the_page_key_has_their_colours():
    env = make_env()
    obs, _ = env.reset(seed=0, options={"start": 0})
    assert legend(obs, every_avatar=True).endswith("@ you  & you, carrying the message")
    assert "& you" not in legend(obs)  # a board's own legend names what it shows
    key = {k["symbol"]: k for k in symbol_key()}
    assert key["&"] == {"symbol": "&", "colour": "#ffc800", "words": "you, carrying the message"}
    grid = np.zeros((GRID, GRID, 4), dtype=np.uint8)
    grid[5, 6, AVATAR_CHANNEL] = AVATAR_WITH_MESSAGE
    cell = next(c for c in board(grid) if c["symbol"] == "&")
    assert cell["colour"] == key["&"]["colour"]  # the key's chip is the board's cell


def test_no_avatar_after_death():
    grid = np.zeros((GRID, GRID, 4), dtype=np.uint8)
    grid[4, 4, 0] = IDENTITIES["sword"]
    assert symbol_at(render_ascii(grid), 4, 4) == "W"
    assert "(no avatar)" in legend(grid)


def test_compact_and_grid_observations_render_identically():
    env = make_env(enemy_movement="chaser")
    obs, _ = env.reset(seed=11, options={"start": 4})
    for a in (RIGHT, RIGHT, DOWN):
        obs, *_ = env.step(a)
    compact = grid_to_compact(obs)
    assert compact.shape == (4, 3)
    assert render_ascii(compact) == render_ascii(obs)
    assert render_ascii(compact, color=True) == render_ascii(obs, color=True)
    assert legend(compact) == legend(obs)
    assert np.array_equal(np.asarray(render_png(compact, cell=16)), np.asarray(render_png(obs, cell=16)))


def test_colour_board_is_the_plain_board_plus_ansi_codes():
    env = make_env()
    obs, _ = env.reset(seed=0, options={"start": 2})
    coloured = render_ascii(obs, color=True)
    assert "\x1b[" in coloured
    assert ANSI.sub("", coloured) == render_ascii(obs)
    # The avatar's code differs from every entity's.
    codes = {symbol: code for code, symbol in re.findall(r"\x1b\[([0-9;]*)m(.)", coloured)}
    assert codes["@"] not in {codes[s] for s in ("D", "Q", "L")}


@pytest.mark.parametrize("shape", [(10, 10, 3), (10, 10), (4, 2), (3, 3), (2, 10, 10, 4), (2, 4, 3), (100, 4)])
def test_wrong_shapes_raise_shape_error(shape):
    bad = np.zeros(shape, dtype=np.uint8)
    with pytest.raises(ShapeError, match="got shape"):
        render_ascii(bad)
    with pytest.raises(ShapeError):
        legend(bad)
    with pytest.raises(ShapeError):
        render_png(bad)


def test_unknown_ids_raise_shape_error():
    grid = np.zeros((GRID, GRID, 4), dtype=np.uint8)
    grid[0, 0, 0] = 99
    with pytest.raises(ShapeError, match="99"):
        render_ascii(grid)


# --------------------------------------------------------------------------- images
def test_png_size_and_cell_colours(tmp_path):
    env = make_env()
    obs, _ = env.reset(seed=0, options={"start": 0})
    path = tmp_path / "board.png"
    cell = 20
    image = render_png(obs, path=path, cell=cell)
    assert image.size == (GRID * cell, GRID * cell)
    assert Image.open(path).size == (GRID * cell, GRID * cell)

    def pixel(r: int, c: int) -> tuple:
        return image.getpixel((c * cell + 3, r * cell + 3))  # inside the cell, off the letter

    ((ar, ac),) = [(r, c) for i, r, c in sprites(obs) if i == AVATAR_NO_MESSAGE]
    assert pixel(ar, ac) != pixel(0, 0), "the avatar's cell is coloured, the empty corner is not"
    dog = next((r, c) for i, r, c in sprites(obs) if i == IDENTITIES["dog"])
    assert pixel(*dog) not in (pixel(ar, ac), pixel(0, 0))
    # A letter is drawn: the avatar's cell holds more than one colour.
    crop = image.crop((ac * cell + 1, ar * cell + 1, (ac + 1) * cell - 1, (ar + 1) * cell - 1))
    assert len(crop.getcolors(maxcolors=10_000)) > 1


def rollout(steps: int) -> tuple[np.ndarray, list[int], list[float]]:
    env = make_env(enemy_movement="chaser", max_steps=steps)
    obs, _ = env.reset(seed=5, options={"start": 1})
    observations, actions, rewards = [obs], [0], [0.0]  # dataset layout: first action a dummy
    for t in range(steps):
        obs, r, term, trunc, _ = env.step(t % 5)
        observations.append(obs)
        actions.append(t % 5)
        rewards.append(r)
        if term or trunc:
            break
    return np.stack(observations), actions, rewards


def test_trajectory_png_wraps_rows(tmp_path):
    observations, actions, rewards = rollout(20)
    t = len(observations)
    path = tmp_path / "traj.png"
    sheet = render_trajectory_png(observations, path, rewards=rewards, actions=actions, cell=12, per_row=4)
    assert path.exists()
    assert Image.open(path).size == sheet.size
    rows = -(-t // 4)
    assert sheet.size[0] > 4 * GRID * 12 and sheet.size[0] < 5 * GRID * 12
    assert sheet.size[1] > rows * GRID * 12
    # T - 1 actions and rewards (between frames) are accepted too; a wrong count is not.
    render_trajectory_png(observations, tmp_path / "b.png", rewards=rewards[1:], actions=actions[1:], cell=8)
    with pytest.raises(ShapeError):
        render_trajectory_png(observations, tmp_path / "c.png", actions=actions[:-3])


def test_trajectory_gif_has_one_frame_per_observation(tmp_path):
    observations, actions, rewards = rollout(6)
    path = tmp_path / "traj.gif"
    render_trajectory_gif(observations, path, rewards=rewards, actions=actions, cell=10, duration_ms=100)
    with Image.open(path) as gif:
        assert gif.n_frames == len(observations)
    compact_path = tmp_path / "compact.gif"
    render_trajectory_gif(grid_to_compact(observations), compact_path, cell=10)
    with Image.open(compact_path) as gif:
        assert gif.n_frames == len(observations)


def test_trajectory_rejects_wrong_shapes(tmp_path):
    with pytest.raises(ShapeError):
        render_trajectory_png(np.zeros((3, 10, 10, 3), np.uint8), tmp_path / "x.png")
    with pytest.raises(ShapeError):
        render_trajectory_gif(np.zeros((10, 10, 4), np.uint8), tmp_path / "x.gif")
    with pytest.raises(ShapeError):
        render_trajectory_gif(np.zeros((0, 4, 3), np.uint8), tmp_path / "x.gif")


# --------------------------------------------------------------------------- play
def play(keys: str, env: MessengerEnv | None = None, start: int | None = 0) -> tuple[int, str, MessengerEnv]:
    env = env or make_env()
    out: list[str] = []
    code = run_game(env, 0, start, line_key_reader(io.StringIO(keys)), out.append)
    return code, "".join(out), env


def last_board(text: str) -> str:
    lines = text.splitlines()
    top = max(i for i, line in enumerate(lines) if line.startswith("+-") and lines[i + 1].startswith("| "))
    return "\n".join(lines[top : top + GRID + 2])


def test_play_scripted_moves_and_quit():
    code, text, env = play("dd\nq\n")
    assert code == 0
    assert env.t == 2
    assert env.avatar == (4, 8), "start 0 puts the avatar in cell (2, 2); two steps right give (2, 4)"
    assert "the dog is the enemy and it is immovable" in text
    assert symbol_at(last_board(text), 2, 4) == "@"
    assert "step 2/32" in text
    assert "quit after 2 steps" in text


def test_play_ignores_unknown_keys_with_a_hint():
    code, text, env = play("z?q")
    assert code == 0
    assert env.t == 0
    assert "unknown key 'z' ignored" in text
    assert "w/a/s/d" in text


def test_play_arrow_keys_and_stay_keys():
    assert split_keys("\x1b[C\x1b[B\x1bOAx") == ["right", "down", "up", "x"]
    code, text, env = play("\x1b[C\x1b[C\x1b[B. xq")
    assert code == 0 and env.t == 6
    assert env.avatar == (6, 8)


def test_play_reports_a_win():
    code, text, env = play("sssss" + "ddddd")  # fetch the message at (7, 2), then the goal at (7, 7)
    assert code == 0 and env.won
    assert "You won" in text
    assert "return +1.5" in text
    assert "The game was: dog (immovable enemy)" in text


def test_play_reports_death_and_time_limit():
    code, text, _ = play("ddddd")  # straight into the enemy at (2, 7)
    assert code == 0 and "You died." in text and "return -1" in text
    code, text, _ = play("....", env=make_env(max_steps=3))
    assert code == 0 and "Time limit" in text and "step 3/3" in text


def test_play_end_of_input_quits_cleanly():
    code, text, env = play("d")
    assert code == 0 and env.t == 1 and "input ended" in text


def test_play_main_rejects_an_out_of_range_index(capsys):
    assert play_main(["--index", "100000"]) == 2
    err = capsys.readouterr().err
    assert "--index must be in 0.." in err and "Traceback" not in err


def test_play_main_rejects_bad_arguments(capsys):
    assert play_main(["--split", "nonsense"]) == 2
    assert play_main(["--start", "24"]) == 2
    assert play_main(["--max-steps", "0"]) == 2
    assert "invalid choice" in capsys.readouterr().err


def test_board_cells_follow_the_picture_rules():
    # The review page draws these cells: the avatar over an entity, two entities sharing a cell.
    from lwm_models.messenger.render import board

    obs = np.array([[2, 3, 3], [5, 3, 3], [10, 6, 6], [15, 6, 6]], dtype=np.uint8)
    cells = {(c["row"], c["col"]): c for c in board(obs)}
    assert set(cells) == {(3, 3), (6, 6)}
    assert cells[(3, 3)]["symbol"] == "*" and sorted(cells[(3, 3)]["under"]) == ["airplane", "bird"]
    assert cells[(6, 6)]["symbol"] == "@" and cells[(6, 6)]["under"] == ["ball"]
    assert all(c["colour"].startswith("#") and len(c["colour"]) == 7 for c in cells.values())

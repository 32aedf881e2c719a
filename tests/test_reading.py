"""What the world model reads each description as about (lwm_models/world/reading.py), and the
world-model server telling a person when a description is about an entity that is not on the board."""

from __future__ import annotations

import copy
from dataclasses import replace

import numpy as np
import pytest

from lwm_models import messages
from lwm_models.data.splits import load_split
from lwm_models.text import DescriptionPools
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.model_server import WorldModelServer
from lwm_models.world.reading import grounding, read_identities, ungrounded_note
from lwm_models.world.shipped import shipped_checkpoint


@pytest.fixture(scope="module")
def emma():
    model, _ = load_checkpoint(shipped_checkpoint("emma"))
    return model, model.frozen_text_encoder()


def test_emma_reads_which_entity_each_description_is_about(emma):
    model, encoder = emma
    pools = DescriptionPools.generated()
    rng = np.random.default_rng(0)
    games = load_split("newall-test")[:20]
    right = total = 0
    for game in games:
        triples = list(game.triples)
        read = read_identities(model, encoder, pools.draw("newall-test", triples, rng))
        right += sum(r == t[0] for r, t in zip(read, triples))
        total += 3
    # text the model was never trained on, of games it never saw: most, not all, are read right
    assert right / total >= 0.8, right / total


def test_models_that_read_no_text_read_no_identity():
    model, _ = load_checkpoint(shipped_checkpoint("observational"))
    assert read_identities(model, None, ["a", "b", "c"]) == [None, None, None]


def test_the_note_names_what_is_off_the_board():
    descriptions = ["the hound is the goal", "the ball has the message", "the plane is deadly"]
    assert ungrounded_note(descriptions, ["ball", "airplane", "robot"][::-1], ["robot", "ball", "airplane"]) is None
    note = ungrounded_note(descriptions, ["dog", "ball", "airplane"], ["robot", "ball", "airplane"])
    assert note == (
        'the world model reads "the hound is the goal" as about the dog, not on this board (robot, ball, airplane)'
    )
    assert grounding(["dog", None], ["ball"]) == [
        {"identity": "dog", "on_board": False},
        {"identity": None, "on_board": False},
    ]


def served_first_game(tmp_path):
    """The shipped world-model server with NewAll test's first game's manual (generated), its game,
    board and the generator's pools."""
    game = load_split("newall-test")[0]
    sim = WorldModelServer(state_path=tmp_path / "state.json")
    pools = DescriptionPools.generated()
    sim.take_env_manual(pools.draw("newall-test", list(game.triples), np.random.default_rng(1)), "newall-test:0:0")
    return sim, game, [e.identity for e in game.entities], pools


def test_the_world_model_server_flags_a_manual_about_another_board(tmp_path):
    sim, game, board, pools = served_first_game(tmp_path)
    status = sim.status()
    assert status["board"] == board and [r["on_board"] for r in status["reading"]] == [True, True, True]
    assert sim.ungrounded() is None

    others = [t for g in load_split("newall-test") for t in g.triples if t[0] not in board]
    foreign = [others[0], next(t for t in others if t[0] != others[0][0])]
    manual = pools.draw("newall-test", [*foreign, game.triples[2]], np.random.default_rng(2))
    sim.set_manual(manual, "human")
    note = sim.ungrounded()
    assert note is not None and "not on this board" in note and foreign[0][0] in note, note
    assert [r["on_board"] for r in sim.status()["reading"]][:2] == [False, False]


def test_the_server_says_which_board_entity_a_grounding_model_takes_a_stray_name_as(tmp_path):
    # The served model grounds its words: one description naming an entity off the board, with one
    # board entity no description names, is taken as about that entity, and the person is told so.
    sim, game, board, pools = served_first_game(tmp_path)
    assert sim.model.ground
    stray = next(t for g in load_split("newall-test") for t in g.triples if t[0] not in board)
    manual = pools.draw("newall-test", [stray, *game.triples[1:]], np.random.default_rng(3))
    sim.set_manual(manual, "human")
    reading = sim.status()["reading"]
    assert reading[0] == {
        "identity": stray[0],
        "on_board": False,
        "grounded_as": board[0],
        **{k: reading[0][k] for k in ("unsure", "guessed") if k in reading[0]},
    }
    assert all("grounded_as" not in r for r in reading[1:])
    note = sim.ungrounded()
    assert f"as about the {stray[0]}, not on this board" in note and f"as about the {board[0]}, the one" in note, note
    messages.dump("status", sim.status())  # the schema takes what the page is sent


def test_the_server_says_a_grounding_model_shares_two_stray_names_out_among_the_board(tmp_path):
    # Two descriptions naming entities off the board, two board entities no description names: each
    # is taken as one of them, a different one each, and the person is told so, in the status and
    # in the note.
    sim, game, board, pools = served_first_game(tmp_path)
    strays = [t for g in load_split("newall-test") for t in g.triples if t[0] not in board]
    two = [strays[0], next(t for t in strays if t[0] != strays[0][0])]
    manual = pools.draw("newall-test", [game.triples[0], *two], np.random.default_rng(3))
    sim.set_manual(manual, "human")
    reading = sim.status()["reading"]
    assert "grounded_among" not in reading[0] and "grounded_as" not in reading[0]
    assert [r["grounded_among"] for r in reading[1:]] == [board[1:], board[1:]]
    note = sim.ungrounded()
    assert f"as about the {board[1]} and the {board[2]}, one each" in note, note
    messages.dump("status", sim.status())  # the schema takes what the page is sent


def test_the_note_and_the_status_name_the_entities_a_description_is_shared_among():
    descriptions = ["the hound is the goal", "the czarina has the message", "the jet is deadly"]
    board = ["robot", "queen", "airplane"]
    read = ["dog", "queen", "airplane"]
    # words naming the dog and the jet... and the queen, one of them named twice by keywords: the
    # grounding model shares the first two out among the robot and the queen
    grounded = [["robot", "queen"], ["robot", "queen"], ["airplane"]]
    status = grounding(read, board, None, grounded)
    assert status[0] == {"identity": "dog", "on_board": False, "grounded_among": ["robot", "queen"]}
    assert status[1] == {"identity": "queen", "on_board": True, "grounded_among": ["robot", "queen"]}
    assert status[2] == {"identity": "airplane", "on_board": True}
    note = ungrounded_note(descriptions, read, board, grounded)
    assert note == (
        'the world model reads "the hound is the goal" as about the dog, not on this board (robot, queen, airplane); '
        'it takes "the hound is the goal" and "the czarina has the message" as about the robot and the queen, '
        "one each, and imagines each way round"
    )


def test_a_model_trained_on_longer_descriptions_reads_them_whole(emma):
    model, encoder = emma
    long_winded = (
        "If you take a careful look around the board you will notice the dog, which, as far as anyone can tell, "
        "never moves; and you should keep in mind that it is the goal, which matters a great deal here."
    )
    short = model.read_manual([long_winded, "a", "b"], encoder)
    assert int(short.mask[0, 0].sum()) == encoder.max_tokens == 36  # cut: the role is past the cut
    longer = copy.deepcopy(model)
    longer.config = replace(model.config, text=replace(model.config.text, max_tokens=64))
    whole = longer.read_manual([long_winded, "a", "b"], encoder)
    assert 36 < int(whole.mask[0, 0].sum()) < 64
    assert encoder.keeping(64) is encoder.keeping(64) and encoder.keeping(36) is encoder
    assert encoder.keeping(64)._model is encoder._model  # one text model in memory, whichever length

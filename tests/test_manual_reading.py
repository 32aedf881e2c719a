"""The manual's reading before any step (lwm_models/world/manual_reading.py): one reading, the same
whatever the order of the descriptions, facts a person states held for sure, questions where it is
unsure, and the served model imagining under it."""

import itertools
from dataclasses import replace

import numpy as np
import pytest
import torch

from lwm_models.errors import LwmError
from lwm_models.messenger.constants import IDENTITIES
from lwm_models.text.stress import load_fresh
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.manual_reading import ASK_BELOW, check_fact
from lwm_models.world.shipped import SYSTEM_WORLD_MODEL, shipped_checkpoint

BOARD = torch.tensor([[IDENTITIES["airplane"], IDENTITIES["mage"], IDENTITIES["ship"]]])
CLEAR = [
    "the plane chases you and it is deadly",
    "the mage never moves and has the secret message",
    "the ship runs away from you and is the goal",
]


@pytest.fixture(scope="module")
def served():
    model, _ = load_checkpoint(shipped_checkpoint(SYSTEM_WORLD_MODEL))
    assert model.reading_calibration is not None, "the shipped default has no reading calibration"
    return model, model.frozen_text_encoder()


def reading(served, descriptions, facts=()):
    model, encoder = served
    batch = replace(model.read_manual(descriptions, encoder), facts=tuple(facts))
    return model.on_board(batch, BOARD).reading


def test_a_clear_manual_is_read_right_and_sure(served):
    got = {e["identity"]: e for e in reading(served, CLEAR).to_json()}
    assert {k: (e["role"], e["movement"]) for k, e in got.items()} == {
        "airplane": ("enemy", "chaser"),
        "mage": ("message", "immovable"),
        "ship": ("goal", "fleeing"),
    }
    assert all(e["p"] >= ASK_BELOW and e["movement_p"] >= ASK_BELOW for e in got.values())
    assert reading(served, CLEAR).questions() == []


def test_the_reading_does_not_depend_on_the_order_of_the_descriptions(served):
    texts = [e.text for e in load_fresh() if e.identity in ("airplane", "mage", "ship")]
    rng = np.random.default_rng(0)
    for _ in range(3):
        manual = [texts[int(i)] for i in rng.choice(len(texts), 3, replace=False)]
        first = reading(served, manual).to_json()
        for order in itertools.permutations(range(3)):
            again = reading(served, [manual[k] for k in order]).to_json()
            for a, b in zip(first, again, strict=True):
                assert (a["role"], a["p"], a["movement"], a["roles"], a["movements"]) == (
                    b["role"], b["p"], b["movement"], b["roles"], b["movements"]
                )  # fmt: skip
                assert again[0]["description"] in range(3)


def test_text_with_no_usable_fact_leaves_every_role_below_half(served):
    junk = [u["text"] for u in load_fresh(unusable=True) if u["kind"] == "gibberish"]
    for start in range(0, len(junk), 3):
        for entity in reading(served, junk[start : start + 3]).to_json():
            assert max(entity["roles"].values()) < 0.5, entity


def test_an_answer_is_held_for_sure_and_settles_what_follows_from_it(served):
    vague = ["the plane is somewhere on the board", "the mage is here too", "there is also a ship"]
    before = reading(served, vague)
    assert before.questions(), "a manual that states nothing asks"
    after = reading(served, vague, [{"entity": "airplane", "field": "role", "value": "enemy"},
                                    {"entity": "mage", "field": "role", "value": "message"}])  # fmt: skip
    roles = {e["identity"]: (e["role"], e["p"]) for e in after.to_json()}
    assert roles["airplane"] == ("enemy", 1.0) and roles["mage"] == ("message", 1.0)
    assert roles["ship"] == ("goal", 1.0)  # each role once: the third follows
    moved = reading(served, vague, [{"entity": "ship", "field": "movement", "value": "fleeing"}])
    assert {e["identity"]: e["movement_p"] for e in moved.to_json()}["ship"] == 1.0


def test_questions_name_the_entity_and_offer_every_choice(served):
    vague = ["the plane is somewhere on the board", "the mage is here too", "there is also a ship"]
    q = reading(served, vague).questions()[0]
    assert q.entity in ("airplane", "mage", "ship")
    assert q.text.startswith(f"Is the {q.entity} ") or q.text.startswith(f"Does the {q.entity} ")
    assert sorted(c["value"] for c in q.to_json()["choices"]) == sorted(q.choices) and len(q.choices) == 3


@pytest.mark.parametrize(
    ("fact", "message"),
    [
        ({"entity": "airplane", "field": "colour", "value": "red"}, "movement or role"),
        ({"entity": "airplane", "field": "role", "value": "friend"}, "no role"),
        ({"entity": "dragon", "field": "role", "value": "enemy"}, "no entity of the game"),
        ({"entity": "dog", "field": "role", "value": "enemy"}, "not on this board"),
    ],
)
def test_a_bad_fact_is_refused_in_plain_words(fact, message):
    with pytest.raises(LwmError, match=message):
        check_fact(fact, ["airplane", "mage", "ship"])


def test_imagination_follows_the_reading(served):
    """The readings imagined are the reading's likeliest, in its proportions: a lone trajectory
    imagines the one it believes."""
    model, encoder = served
    manual = model.on_board(model.read_manual(CLEAR, encoder), BOARD)
    cond = model.condition_on(manual)
    configs = manual.reading.configurations()
    assert len(cond.reading_log_prior) == len(configs)
    assert np.allclose(cond.reading_log_prior.exp().numpy(), [p for _, p in configs], atol=1e-5)
    believed = (("airplane", "chaser", "enemy"), ("mage", "immovable", "message"), ("ship", "fleeing", "goal"))
    assert configs[0][0] == believed


def test_an_entity_that_left_the_board_keeps_its_reading(served):
    """Once the message is picked up the board shows two entities: the reading stays the one the
    start was read with (the monitor imagines from such boards)."""
    model, encoder = served
    batch = model.read_manual(CLEAR, encoder)
    whole = model.on_board(batch, BOARD).reading.to_json()
    without_mage = torch.tensor([[IDENTITIES["airplane"], 0, IDENTITIES["ship"]]])
    assert model.on_board(batch, without_mage).reading.to_json() == whole

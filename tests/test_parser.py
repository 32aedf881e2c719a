"""The offline keyword parser that routes descriptions for GPTHard."""

from __future__ import annotations

from pathlib import Path

import pytest

from lwm_models.messenger.constants import ALL_TRIPLES, IDENTITIES
from lwm_models.text import generate_descriptions, load_description_file
from lwm_models.text.parser import parse_description, parser_accuracy, route_identity_id

VAL = Path(__file__).resolve().parents[2] / "shared" / "data" / "messenger-texts" / "text_val.json"


def test_generated_descriptions_parse_back_to_their_triple():
    texts = {t: generate_descriptions(t) for t in ALL_TRIPLES}
    acc = parser_accuracy(texts)
    assert acc["identity"] == 1.0
    assert acc["movement"] > 0.95 and acc["role"] > 0.9, acc


@pytest.mark.parametrize(
    "text, expected",
    [
        ("the falcon that never moves is the deadly enemy.", ("bird", "immovable", "enemy")),
        ("the scholar running away from you holds the secret document.", ("scientist", "fleeing", "message")),
        ("the humanoid coming toward you is the goal.", ("robot", "chaser", "goal")),
        ("an unmoving jet has the classified note.", ("airplane", "immovable", "message")),
    ],
)
def test_examples(text, expected):
    assert parse_description(text) == expected


def test_routing():
    assert route_identity_id("the hound is deadly") == IDENTITIES["dog"]
    assert route_identity_id("something unspeakable") == 0


@pytest.mark.skipif(not VAL.is_file(), reason="shared human-written descriptions not available")
def test_accuracy_on_held_out_human_descriptions():
    # The keyword lists were written looking only at text_train.json's misparses.
    acc = parser_accuracy(load_description_file(VAL))
    assert acc["identity"] >= 0.95 and acc["movement"] >= 0.85 and acc["role"] >= 0.9, acc

"""The game splits follow the rules of docs/game.md, "The benchmark"."""

from __future__ import annotations

from itertools import product

import pytest

from lwm_models.data.splits import SPLIT_SIZES, GameSplits, default_splits, make_splits
from lwm_models.messenger.constants import MOVEMENTS, TRAIN_TRIPLES


@pytest.fixture(scope="module")
def splits():
    return default_splits(0)


def test_counts_are_exact(splits):
    assert splits.counts() == SPLIT_SIZES
    assert SPLIT_SIZES == {
        "train": 1536,
        "newcombo-dev": 896,
        "newcombo-test": 896,
        "newattr-dev": 204,
        "newattr-test": 204,
        "newall-dev": 856,
        "newall-test": 856,
    }


def test_no_game_is_in_two_splits(splits):
    seen = {}
    for name, games in splits.splits.items():
        assert len(set(games)) == len(games), f"{name} repeats a game"
        for g in games:
            assert g not in seen, f"{g} in {seen.get(g)} and {name}"
            seen[g] = name


def test_training_uses_the_48_triples_and_all_movement_combinations(splits):
    train = splits["train"]
    assert {t for g in train for t in g.triples} == set(TRAIN_TRIPLES)
    assert len(TRAIN_TRIPLES) == 48
    combos = {tuple(e.movement for e in g.entities) for g in train}
    assert combos == set(product(MOVEMENTS, repeat=3))


def test_each_split_has_its_defining_property(splits):
    train_sets = {g.identity_set for g in splits["train"]}
    for name in ("newcombo-dev", "newcombo-test"):
        for g in splits[name]:
            assert all(t in TRAIN_TRIPLES for t in g.triples)
            assert g.identity_set not in train_sets
    for name in ("newattr-dev", "newattr-test"):
        for g in splits[name]:
            assert not any(t in TRAIN_TRIPLES for t in g.triples)
            assert g.identity_set in train_sets
    for name in ("newall-dev", "newall-test"):
        for g in splits[name]:
            assert not any(t in TRAIN_TRIPLES for t in g.triples)
            assert g.identity_set not in train_sets


def test_splits_are_seeded(splits):
    again = make_splits(0)
    assert again.splits == splits.splits
    other = make_splits(1)
    assert other.counts() == SPLIT_SIZES
    assert other["train"] != splits["train"]


def test_json_round_trip(splits, tmp_path):
    path = tmp_path / "splits.json"
    splits.save(path)
    import json

    assert GameSplits.from_json(json.loads(path.read_text())).splits == splits.splits

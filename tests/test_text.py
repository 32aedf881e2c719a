"""Manual text: the generator's lexicon and output, the human-written file loader, per-split pools."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from lwm_models.errors import InvalidSpecError, LwmError, TextFileError
from lwm_models.messenger.constants import ALL_TRIPLES, IDENTITIES, MOVEMENTS, ROLES, SPLITS, TRAIN_TRIPLES
from lwm_models.text import (
    IDENTITY_SYNONYMS,
    MOVEMENT_PHRASES,
    ROLE_PHRASES,
    DescriptionPools,
    PoolError,
    add_typos,
    generate_descriptions,
    load_description_file,
    load_description_files,
    split_counts,
)

TEXTS = Path(__file__).resolve().parents[2] / "shared" / "data" / "messenger-texts"
TRAIN_SPLITS = {"train", "newcombo-dev", "newcombo-test"}
UNSEEN_SPLITS = {"newattr-dev", "newattr-test", "newall-dev", "newall-test"}


def _has_phrase(text: str, phrase: str) -> bool:
    return re.search(rf"\b{re.escape(phrase)}\b", text) is not None


def _parse(text: str) -> tuple[set[str], set[str], set[str]]:
    """A longest-match-first parse with the exposed lexicon: the labels found for each slot."""
    phrases = [(p, "identity", k) for k, v in IDENTITY_SYNONYMS.items() for p in v]
    phrases += [(p, "role", k) for k, v in ROLE_PHRASES.items() for p in v]
    phrases += [(p, "movement", k) for k, v in MOVEMENT_PHRASES.items() for p in v]
    taken = [False] * len(text)
    found: dict[str, set[str]] = {"identity": set(), "role": set(), "movement": set()}
    for phrase, slot, label in sorted(phrases, key=lambda x: -len(x[0])):
        for m in re.finditer(rf"\b{re.escape(phrase)}\b", text):
            if not any(taken[m.start() : m.end()]):
                taken[m.start() : m.end()] = [True] * (m.end() - m.start())
                found[slot].add(label)
    return found["identity"], found["movement"], found["role"]


@pytest.fixture(scope="module")
def generated() -> dict:
    return {t: generate_descriptions(t) for t in ALL_TRIPLES}


@pytest.fixture(scope="module")
def human_files() -> list[Path]:
    if not TEXTS.is_dir():
        pytest.skip("shared human-written descriptions not available")
    return [TEXTS / "text_train.json", TEXTS / "text_val.json"]


# ---------------------------------------------------------------- generator


def test_generator_counts_and_format(generated):
    every = [d for texts in generated.values() for d in texts]
    assert len(set(every)) >= 3000
    assert len(set(every)) == len(every), "a description belongs to two triples"
    for triple, texts in generated.items():
        assert 14 <= len(texts) <= 200, triple
        assert len(set(texts)) == len(texts)
        for d in texts:
            assert d == d.lower() and d.endswith(".") and "  " not in d, d
    assert generate_descriptions(ALL_TRIPLES[5]) == generated[ALL_TRIPLES[5]]


def test_lexicon_is_unambiguous():
    assert set(IDENTITY_SYNONYMS) == set(IDENTITIES)
    assert set(ROLE_PHRASES) == set(ROLES) and set(MOVEMENT_PHRASES) == set(MOVEMENTS)
    owners: dict[str, str] = {}
    for ident, synonyms in IDENTITY_SYNONYMS.items():
        assert len(synonyms) >= 5 and ident in synonyms
        for syn in synonyms:
            assert owners.setdefault(syn, ident) == ident, f"{syn!r} names {owners[syn]} and {ident}"
    others = [p for v in ROLE_PHRASES.values() for p in v] + [p for v in MOVEMENT_PHRASES.values() for p in v]
    for phrase in others:
        assert not any(_has_phrase(phrase, syn) for syn in owners), phrase


def test_every_description_names_its_triple(generated):
    for (ident, mov, role), texts in generated.items():
        mine = IDENTITY_SYNONYMS[ident]
        theirs = [s for other, syns in IDENTITY_SYNONYMS.items() if other != ident for s in syns]
        for d in texts:
            assert any(_has_phrase(d, s) for s in mine), d
            assert not any(_has_phrase(d, s) for s in theirs), d
            assert _parse(d) == ({ident}, {mov}, {role}), d


def test_generator_uses_the_whole_lexicon(generated):
    every = " ".join(d for texts in generated.values() for d in texts)
    for table in (IDENTITY_SYNONYMS, ROLE_PHRASES, MOVEMENT_PHRASES):
        for phrases in table.values():
            for p in phrases:
                assert p in every, p


def test_generator_rejects_unknown_names():
    for bad in [("unicorn", "chaser", "enemy"), ("dog", "teleporting", "enemy"), ("dog", "chaser", "boss")]:
        with pytest.raises(InvalidSpecError, match=f"unknown .*{bad[0] if bad[0] == 'unicorn' else ''}"):
            generate_descriptions(bad)


def test_typos(generated):
    rng = np.random.default_rng(0)
    texts = generated[("ship", "fleeing", "enemy")]
    for text in texts:
        assert add_typos(text, rng, 0.0) == text
        typo = add_typos(text, rng, 1.0)
        assert typo != text and typo.endswith(".")
        assert len(typo.split(" ")) == len(text.split(" "))
    some = [add_typos(t, rng, 0.1) for t in texts]
    assert 0 < sum(a != b for a, b in zip(some, texts)) < len(texts)
    for short in ["a", "ab.", "zzz", "a b c"]:
        for _ in range(20):
            assert add_typos(short, rng, 1.0).strip()
    a = add_typos(texts[0], np.random.default_rng(3), 0.5)
    assert a == add_typos(texts[0], np.random.default_rng(3), 0.5)


# ---------------------------------------------------------------- human-written files


def test_loader_reads_the_real_files(human_files):
    for path in human_files:
        data = load_description_file(path)
        assert data and set(data) <= set(ALL_TRIPLES)
        assert all(mov in MOVEMENTS for _, mov, _ in data)
        assert all(texts and all(isinstance(t, str) and t for t in texts) for texts in data.values())
    merged = load_description_files(human_files)
    assert set(merged) <= set(ALL_TRIPLES)
    assert sum(len(v) for v in merged.values()) > 1000
    for triple, texts in merged.items():
        assert len(set(texts)) == len(texts), triple


def _write(tmp_path: Path, content, name: str = "texts.json") -> Path:
    path = tmp_path / name
    path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


GOOD = {"airplane": {"enemy": {"chaser": ["the jet hunts you and is deadly."], "unknown": ["a jet."]}}}


@pytest.mark.parametrize(
    "content, expected",
    [
        ("{not json", "not valid JSON"),
        ([1, 2], "top level must be a JSON object"),
        ({"unicorn": {}}, "unknown identity 'unicorn'"),
        ({"airplane": {"villain": {}}}, r"unknown role 'villain' at airplane\.villain"),
        ({"airplane": {"enemy": {"walking": []}}}, r"unknown movement 'walking' at airplane\.enemy\.walking"),
        ({"airplane": ["x"]}, "airplane must be a JSON object"),
        ({"airplane": {"enemy": ["x"]}}, r"airplane\.enemy must be a JSON object"),
        ({"airplane": {"enemy": {"chaser": "the jet."}}}, r"airplane\.enemy\.chaser must be a list"),
        ({"airplane": {"enemy": {"chaser": ["ok.", 3]}}}, r"chaser\[1\] must be a non-empty string"),
        ({"airplane": {"enemy": {"chaser": ["  "]}}}, r"chaser\[0\] must be a non-empty string"),
        ({"airplane": {"enemy": {"unknown": ["x."]}}, "dog": {"goal": {"chaser": []}}}, "no usable"),
        ({}, "no usable description"),
    ],
)
def test_loader_rejects_malformed_files(tmp_path, content, expected):
    path = _write(tmp_path, content)
    with pytest.raises(TextFileError, match=expected) as info:
        load_description_file(path)
    assert str(path) in str(info.value)


def test_loader_missing_file(tmp_path):
    with pytest.raises(TextFileError, match="no such description file"):
        load_description_file(tmp_path / "missing.json")
    with pytest.raises(TextFileError, match="missing.json"):
        load_description_files([_write(tmp_path, GOOD), tmp_path / "missing.json"])
    with pytest.raises(TextFileError, match="no description file"):
        load_description_files([])


def test_loader_skips_unknown_and_empty_and_merges(tmp_path):
    first = dict(GOOD)
    first["dog"] = {"goal": {"fleeing": [], "immovable": ["the hound stays.", "the hound stays."]}}
    second = {"airplane": {"enemy": {"chaser": ["a second one.", "the jet hunts you and is deadly."]}}}
    a, b = _write(tmp_path, first, "a.json"), _write(tmp_path, second, "b.json")
    assert load_description_file(a) == {
        ("airplane", "chaser", "enemy"): ["the jet hunts you and is deadly."],
        ("dog", "immovable", "goal"): ["the hound stays."],
    }
    merged = load_description_files([a, b])
    assert merged[("airplane", "chaser", "enemy")] == ["the jet hunts you and is deadly.", "a second one."]
    assert ("dog", "fleeing", "goal") not in merged


# ---------------------------------------------------------------- pools


@pytest.mark.parametrize("n", range(0, 30))
def test_split_counts(n):
    for shares in ([2, 1, 1], [1, 1, 2, 2]):
        counts = split_counts(n, shares)
        assert sum(counts) == n and min(counts) >= 0
        if n >= len(shares):
            assert min(counts) >= 1
        for c, w in zip(counts, shares):
            assert abs(c - n * w / sum(shares)) < 2


@pytest.fixture(scope="module", params=["generated", "human"])
def pools(request, human_files_or_none) -> DescriptionPools:
    if request.param == "generated":
        return DescriptionPools.generated(seed=0)
    if human_files_or_none is None:
        pytest.skip("shared human-written descriptions not available")
    return DescriptionPools.from_files(human_files_or_none, seed=0)


@pytest.fixture(scope="module")
def human_files_or_none() -> list[Path] | None:
    return [TEXTS / "text_train.json", TEXTS / "text_val.json"] if TEXTS.is_dir() else None


def test_pools_are_disjoint_and_cover_their_triples(pools):
    assert set(pools.pools) == set(SPLITS)
    owner: dict[str, str] = {}
    for split, by_triple in pools.pools.items():
        expected = TRAIN_TRIPLES if split in TRAIN_SPLITS else set(ALL_TRIPLES) - TRAIN_TRIPLES
        assert set(by_triple) == set(expected), split
        for triple, texts in by_triple.items():
            assert isinstance(texts, tuple) and texts, (split, triple)
            assert pools.pool(split, triple) == texts
            for text in texts:
                assert owner.setdefault(text, split) == split, f"{text!r} in {owner[text]} and {split}"
    summary = pools.summary()
    assert set(summary) == set(SPLITS) and all(v > 0 for v in summary.values())
    assert sum(summary.values()) == len(owner)


def test_generated_pool_shares():
    pools = DescriptionPools.generated()
    for triple in ALL_TRIPLES:
        n = len(generate_descriptions(triple))
        if triple in TRAIN_TRIPLES:
            assert abs(len(pools.pool("train", triple)) - n / 2) <= 1
            assert abs(len(pools.pool("newcombo-test", triple)) - n / 4) <= 1
        else:
            assert abs(len(pools.pool("newattr-dev", triple)) - n / 6) <= 1
            assert abs(len(pools.pool("newall-test", triple)) - n / 3) <= 1
        union = {t for s in SPLITS if triple in pools.pools[s] for t in pools.pool(s, triple)}
        assert union == set(generate_descriptions(triple))


def test_pools_depend_on_the_seed_only(human_files_or_none):
    assert DescriptionPools.generated(seed=0).pools == DescriptionPools.generated(seed=0).pools
    assert DescriptionPools.generated(seed=0).pools != DescriptionPools.generated(seed=1).pools
    if human_files_or_none is not None:
        a = DescriptionPools.from_files(human_files_or_none, seed=0)
        assert a.pools == DescriptionPools.from_files(human_files_or_none, seed=0).pools
        assert a.pools != DescriptionPools.from_files(human_files_or_none, seed=7).pools


def test_pool_errors():
    pools = DescriptionPools.generated()
    train = sorted(TRAIN_TRIPLES)[0]
    unseen = next(t for t in ALL_TRIPLES if t not in TRAIN_TRIPLES)
    with pytest.raises(PoolError, match="no descriptions of"):
        pools.pool("newall-test", train)
    with pytest.raises(KeyError):
        pools.pool("train", unseen)
    with pytest.raises(LwmError, match="unknown split"):
        pools.pool("holdout", train)
    with pytest.raises(LwmError, match="seed"):
        DescriptionPools.generated(seed=-1)


def test_draw(pools):
    rng = np.random.default_rng(0)
    train = sorted(TRAIN_TRIPLES)[:3]
    unseen = [t for t in ALL_TRIPLES if t not in TRAIN_TRIPLES][:3]
    for split, triples in [("train", train), ("newcombo-dev", train[::-1]), ("newall-dev", unseen)]:
        seen = [set() for _ in triples]
        for _ in range(60):
            manual = pools.draw(split, triples, rng)
            assert len(manual) == len(triples)
            for k, (text, triple) in enumerate(zip(manual, triples)):
                assert text in pools.pool(split, triple)
                seen[k].add(text)
        for k, triple in enumerate(triples):
            assert len(seen[k]) > 1 or len(pools.pool(split, triple)) == 1
    with pytest.raises(PoolError):
        pools.draw("train", [unseen[0]], rng)
    assert pools.draw("train", [], rng) == []
    assert pools.draw("train", [list(train[0])], np.random.default_rng(1)) == pools.draw(
        "train", [train[0]], np.random.default_rng(1)
    )


def test_draw_with_typos():
    pools = DescriptionPools.generated(typo_rate=0.3)
    triple = sorted(TRAIN_TRIPLES)[0]
    rng = np.random.default_rng(0)
    drawn = [pools.draw("train", [triple], rng)[0] for _ in range(50)]
    assert sum(d not in pools.pool("train", triple) for d in drawn) > 25
    with pytest.raises(LwmError, match="typo_rate"):
        DescriptionPools.generated(typo_rate=1.5)


def test_human_pools_and_fallbacks(human_files):
    pools = DescriptionPools.from_files(human_files, seed=0)
    assert str(human_files[0]) in pools.source and pools.source != "generated"
    assert isinstance(pools.fallback_count, int) and pools.fallback_count == len(pools.fallbacks)
    human = {t for texts in load_description_files(human_files).values() for t in texts}
    generated = DescriptionPools.generated(seed=0)
    for split, by_triple in pools.pools.items():
        for triple, texts in by_triple.items():
            if (split, triple) in pools.fallbacks:
                assert set(texts) <= set(generated.pool(split, triple))
            else:
                assert set(texts) <= human
    assert DescriptionPools.generated().fallback_count == 0


def test_fallbacks_fill_triples_the_files_leave_empty(tmp_path):
    triple = sorted(TRAIN_TRIPLES)[0]
    ident, mov, role = triple
    texts = [f"human text number {k}." for k in range(8)]
    path = _write(tmp_path, {ident: {role: {mov: texts}}})
    pools = DescriptionPools.from_files([path], seed=0)
    generated = DescriptionPools.generated(seed=0)
    expected = {(s, t) for t in ALL_TRIPLES for s in (TRAIN_SPLITS if t in TRAIN_TRIPLES else UNSEEN_SPLITS)}
    expected -= {(s, triple) for s in TRAIN_SPLITS}
    assert set(pools.fallbacks) == expected and pools.fallback_count == len(expected)
    for split, t in pools.fallbacks:
        assert pools.pool(split, t) == generated.pool(split, t)
    assert sorted(t for s in TRAIN_SPLITS for t in pools.pool(s, triple)) == sorted(texts)
    assert len(pools.pool("train", triple)) == 4

    # a triple with fewer descriptions than receiving splits: the missing splits fall back
    few = _write(tmp_path, {ident: {role: {mov: ["only one."]}}}, "few.json")
    pools = DescriptionPools.from_files([few], seed=0)
    got = [s for s in TRAIN_SPLITS if (s, triple) not in pools.fallbacks]
    assert len(got) == 1 and pools.pool(got[0], triple) == ("only one.",)


def test_draw_without_split_uses_every_split():
    pools = DescriptionPools.generated()
    for triple in [sorted(TRAIN_TRIPLES)[0], next(t for t in ALL_TRIPLES if t not in TRAIN_TRIPLES)]:
        union = {t for s in SPLITS if triple in pools.pools[s] for t in pools.pool(s, triple)}
        assert set(pools.pool(None, triple)) == union == set(generate_descriptions(triple))
        rng = np.random.default_rng(0)
        drawn = {pools.draw(None, [triple], rng)[0] for _ in range(300)}
        assert drawn <= union
        assert len({s for s in SPLITS for t in drawn if t in pools.pools[s].get(triple, ())}) > 1

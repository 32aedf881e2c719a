"""The free-form stress set (lwm_models/text/stress_set.json) and what reads it."""

from __future__ import annotations

import json
import re
from collections import Counter

import pytest

from lwm_models.cli import main as cli_main
from lwm_models.data.dataset import generate_dataset
from lwm_models.messenger.constants import ALL_TRIPLES, SPLITS
from lwm_models.text import DescriptionPools, generate_descriptions
from lwm_models.text.pools import receiving_splits
from lwm_models.text.stress import load_stress, stress_pools, stress_styles, stress_texts
from lwm_models.world.shipped import SHIPPED


def test_every_style_covers_every_triple_in_every_part():
    styles = stress_styles()
    assert len(styles) >= 6 and {"casual", "negation", "typos", "rare-synonyms"} <= set(styles)
    counts = Counter((e.split, e.style, e.triple) for e in load_stress())
    for style in styles:
        for triple in ALL_TRIPLES:
            assert counts[("tune", style, triple)] >= 1 and counts[("heldout", style, triple)] >= 2, (style, triple)
            assert counts[("dev", style, triple)] >= 1, (style, triple)
            assert counts[("written", style, triple)] == 1, (style, triple)


def test_the_parts_differ_in_wording_not_just_rows():
    tune, dev, heldout, written = (load_stress(p) for p in ("tune", "dev", "heldout", "written"))

    # word trigrams shared by two parts: few, since templates and phrase banks differ
    def trigrams(entries):
        out = set()
        for e in entries:
            words = re.findall(r"[a-z']+", e.text.lower())
            out.update(zip(words, words[1:], words[2:]))
        return out

    for a, b in ((tune, heldout), (dev, heldout), (tune, dev), (heldout, written), (tune, written), (dev, written)):
        assert not {e.text for e in a} & {e.text for e in b}
        shared = trigrams(a) & trigrams(b)
        assert len(shared) / len(trigrams(b)) < 0.1, sorted(shared)[:20]
    # and none of the set is the project's generator's text
    generated = {t for triple in ALL_TRIPLES for t in generate_descriptions(triple)}
    assert not generated & {e.text for e in tune + dev + heldout + written}


def test_stress_pools_have_the_shape_of_the_benchmark_pools():
    pools = stress_pools("negation")
    assert pools.source == "stress:heldout:negation"
    for triple in ALL_TRIPLES:
        for split in SPLITS:
            has = triple in pools.pools[split]
            assert has == (split in receiving_splits(triple)), (split, triple)
    assert set(pools.pool("newall-test", ("dog", "fleeing", "enemy"))) == set(
        stress_texts("heldout", "negation")[("dog", "fleeing", "enemy")]
    )
    with pytest.raises(Exception, match="unknown stress-set style"):
        stress_pools("shouting")


@pytest.fixture(scope="module")
def newall(tmp_path_factory):
    out = tmp_path_factory.mktemp("newall")
    generate_dataset(out, DescriptionPools.generated(), max_games=4, splits=("newall-test",))
    return out


def test_eval_says_how_many_slots_it_filled_with_generated_text(newall, tmp_path, capsys):
    # a description file with one triple only: nearly every slot is filled from the generator
    texts = tmp_path / "one.json"
    texts.write_text(json.dumps({"dog": {"goal": {"chaser": ["the hound runs at you and wants the note."]}}}))
    base = ["eval", "--checkpoint", str(SHIPPED["observational"]), "--data", str(newall), "--splits", "newall-test"]
    base += ["--loss-episodes", "4", "--imagination-episodes", "0", "--texts", str(texts)]
    out = tmp_path / "r.json"
    assert cli_main.main(base + ["--out", str(out)]) == 0
    err = capsys.readouterr().err
    record = json.loads(out.read_text())["filled_slots"]["newall-test"]
    assert record["slots"] == 12 and record["filled"] >= 11
    assert f"warning: newall-test: {record['filled']} of 12 manual slots" in err
    assert cli_main.main(base + ["--no-fill"]) == 2
    assert "refused" in capsys.readouterr().err


def test_eval_reads_a_stress_style(newall, tmp_path):
    out = tmp_path / "r.json"
    argv = ["eval", "--checkpoint", str(SHIPPED["observational"]), "--data", str(newall), "--splits", "newall-test"]
    argv += ["--loss-episodes", "4", "--imagination-episodes", "0", "--stress", "typos", "--out", str(out)]
    assert cli_main.main(argv) == 0
    record = json.loads(out.read_text())
    assert record["texts"] == "stress:heldout:typos" and record["filled_slots"]["newall-test"]["filled"] == 0


def test_generating_one_split_gives_the_same_episodes_as_generating_all(tmp_path):
    # benchmarks/language_robustness.py runs on `lwm data generate --splits newall-test`: it must
    # hold the very episodes and manuals of the full dataset's NewAll test
    import numpy as np

    one, every = tmp_path / "one", tmp_path / "all"
    common = ["--max-games", "2", "--episodes-per-game", "1", "--no-progress"]
    assert cli_main.main(["data", "generate", "--out", str(one), "--splits", "newall-test", *common]) == 0
    assert cli_main.main(["data", "generate", "--out", str(every), *common]) == 0
    assert sorted(p.name for p in one.iterdir() if p.is_dir()) == ["newall-test"]
    for name in ("observations.npy", "actions.npy", "manuals.npy", "parses.npy"):
        assert np.array_equal(np.load(one / "newall-test" / name), np.load(every / "newall-test" / name)), name
    assert (one / "newall-test" / "texts.json").read_text() == (every / "newall-test" / "texts.json").read_text()


def test_the_training_mix_writes_from_the_tuning_bank_only():
    from lwm_models.text.free_form import STYLES, training_texts

    triples = [("dog", "chaser", "enemy"), ("queen", "immovable", "goal")]
    texts = training_texts(triples, per_style=5, seed=3)
    assert texts == training_texts(triples, per_style=5, seed=3)  # deterministic in its seed
    heldout = {e.text for e in load_stress("heldout")}
    for triple in triples:
        made = texts[triple]
        assert len(made) == len(set(made))
        assert set(generate_descriptions(triple)) <= set(made)
        free = [t for t in made if t not in set(generate_descriptions(triple))]
        assert len(free) >= 4 * len(STYLES)  # a few of each style (duplicates dropped)
        assert not set(free) & heldout
    # the free-form part names the triple's own identity and never the other entity's
    assert all("queen" not in t for t in texts[("dog", "chaser", "enemy")])
    # --mix-source: one of the two parts alone
    generated = training_texts(triples, per_style=5, seed=3, source="generated")
    free_form = training_texts(triples, per_style=5, seed=3, source="free-form")
    for triple in triples:
        assert set(generated[triple]) == set(generate_descriptions(triple))
        assert set(free_form[triple]) == set(texts[triple]) - set(generate_descriptions(triple))
    with pytest.raises(ValueError, match="unknown mix source"):
        training_texts(triples, source="books")

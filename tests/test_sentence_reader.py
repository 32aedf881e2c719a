"""The sentence reader (lwm_models/world/sentence_reader.py): the text encoder tuned to read a
description's movement and role, cross-fitted over folds, shipped beside the default checkpoint."""

import json
import shutil

import numpy as np
import pytest
import torch

from lwm_models.errors import LwmError
from lwm_models.messenger.constants import ALL_TRIPLES, MOVEMENTS, ROLES
from lwm_models.text.generator import generate_descriptions
from lwm_models.text.stress import load_fresh
from lwm_models.world.manual_reading import CALIBRATION_FILE, Calibration
from lwm_models.world.sentence_reader import (
    SENTENCE_FILE,
    SUBJECTS,
    SentenceReader,
    SentenceReaderConfig,
    fit_sentence_reader,
)
from lwm_models.world.shipped import SYSTEM_WORLD_MODEL, shipped_checkpoint

TEXTS = ["the plane chases you and it is deadly", "a mage that never moves", "ship = goal, runs off"]


@pytest.fixture(scope="module")
def untrained():
    """A reader whose folds differ: random updates where training would have put them."""
    torch.manual_seed(0)
    reader = SentenceReader(SentenceReaderConfig(folds=2))
    with torch.no_grad():
        for layer in reader.adapted:
            layer.b.normal_(0, 0.05)
        reader.head_weight.normal_(0, 0.1)
    return reader


def test_every_fold_at_once_reads_as_each_fold_alone(untrained):
    together = untrained.logits(TEXTS)
    for k in range(2):
        alone = untrained.logits(TEXTS, fold=k)[0]
        assert torch.allclose(together[k], alone, atol=1e-5)
    assert not torch.allclose(together[0], together[1], atol=1e-3), "the folds' updates were not applied"


def test_a_reader_reads_the_same_after_its_file_round_trip(untrained, tmp_path):
    untrained.save(tmp_path / SENTENCE_FILE)
    again = SentenceReader.load(tmp_path / SENTENCE_FILE)
    before, after = untrained.log_probs(TEXTS), again.log_probs(TEXTS)
    for name in before:  # saved in half precision
        assert np.allclose(before[name], after[name], atol=2e-2)
        assert (before[name].argmax(1) == after[name].argmax(1)).all()


def test_a_calibration_naming_a_missing_reader_is_refused(tmp_path):
    shutil.copy(shipped_checkpoint(SYSTEM_WORLD_MODEL) / CALIBRATION_FILE, tmp_path / CALIBRATION_FILE)
    with pytest.raises(LwmError, match="cannot read the sentence reader"):
        Calibration.load(tmp_path / CALIBRATION_FILE)
    doc = json.loads((tmp_path / CALIBRATION_FILE).read_text())
    (tmp_path / CALIBRATION_FILE).write_text(json.dumps({**doc, "sentence": None}))
    assert Calibration.load(tmp_path / CALIBRATION_FILE).sentence is None


def test_fitting_reads_text_it_never_saw_better_than_chance():
    texts, movement, role = [], [], []
    for t in ALL_TRIPLES:
        for text in generate_descriptions(t)[::30][:3]:  # three of its templates
            texts.append(text)
            movement.append(MOVEMENTS.index(t[1]))
            role.append(ROLES.index(t[2]))
    described = len(texts)
    rng = np.random.default_rng(0)
    letters = list("abcdefghijklmnopqrstuvwxyz")
    texts += [" ".join("".join(rng.choice(letters, size=5)) for _ in range(4)) for _ in range(60)]  # says nothing
    subject = [SUBJECTS.index("entity")] * described + [SUBJECTS.index("nothing")] * 60
    truth = {"movement": np.array(movement + [0] * 60), "role": np.array(role + [0] * 60), "subject": np.array(subject)}
    known = {name: np.arange(len(texts)) < described for name in ("movement", "role")}
    known["subject"] = np.ones(len(texts), dtype=bool)
    folds = rng.integers(2, size=len(texts))
    cfg = SentenceReaderConfig(steps=80, batch=16, lr=3e-3, warmup=10)
    _, held_out = fit_sentence_reader(texts, truth, known, np.ones(len(texts)), folds, cfg, progress=lambda _: None)
    for name, y in truth.items():
        right = (held_out[name].argmax(1) == y)[known[name]].mean()
        assert right > 0.6, f"{name}: {right:.2f} of descriptions no fold had seen read right"
    # An unstated fact is trained towards even odds: letters that say nothing read as saying nothing.
    surest = np.exp(held_out["role"][described:]).max(1)
    assert surest.mean() < 0.5, f"random letters read with a role {surest.mean():.0%} sure"


def test_the_shipped_reader_alone_reads_the_fresh_held_out_part():
    """Measured 93% of roles and 97% of movements (324 descriptions, nothing fitted on them); all but
    one read as about an entity of the game, and 24 of its 30 descriptions of gibberish and other
    games' things as about none."""
    reader = Calibration.load(shipped_checkpoint(SYSTEM_WORLD_MODEL) / CALIBRATION_FILE).sentence
    assert reader is not None, "the shipped default has no sentence reader"
    fresh = load_fresh()
    read = reader.log_probs([e.text for e in fresh])
    for name, values in (("movement", MOVEMENTS), ("role", ROLES)):
        right = np.mean([values[int(lp.argmax())] == getattr(e, name) for lp, e in zip(read[name], fresh)])
        assert right >= 0.9, f"{name}: {right:.1%} right"
    about_entity = np.exp(read["subject"][:, SUBJECTS.index("entity")]) >= 0.5
    assert about_entity.mean() >= 0.98, f"{1 - about_entity.mean():.1%} of descriptions read as about nothing"
    junk = [u["text"] for u in load_fresh(unusable=True) if u["kind"] in ("gibberish", "other-game")]
    stray = np.exp(reader.log_probs(junk)["subject"][:, SUBJECTS.index("entity")]) < 0.5
    assert stray.mean() >= 0.7, f"only {stray.mean():.0%} of gibberish and other games' text read as about nothing"

"""`lwm tune-reader` on the shipped EMMA-LWM and a tiny generated dataset: only the reader changes,
other words come to be read as the dataset's words of the same triple, and a run resumes exactly."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from lwm_models.data.dataset import generate_dataset
from lwm_models.errors import LwmError
from lwm_models.messenger.constants import ALL_TRIPLES
from lwm_models.text import DescriptionPools
from lwm_models.text.free_form import training_texts
from lwm_models.world.checkpoint import load_checkpoint
from lwm_models.world.reader_tuning import ReaderTuningArgs, dataset_descriptions, reading, tune_reader
from lwm_models.world.shipped import shipped_checkpoint
from lwm_models.world.training_data import SplitTokens


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("data")
    generate_dataset(out, DescriptionPools.generated(), max_games=12, train_episodes_per_game=6)
    return out


def run_args(data: Path, out: Path, **kw) -> ReaderTuningArgs:
    base = dict(
        init=str(shipped_checkpoint("emma")),
        data=str(data),
        out=str(out),
        steps=24,
        batch=8,
        lr=1e-3,
        warmup=2,
        mix_source="free-form",
        mix_per_style=2,
        splice=64,
        eval_every=12,
        eval_episodes=8,
        progress=False,
    )
    return ReaderTuningArgs(**{**base, **kw})


def reading_error(model, teacher, data: SplitTokens) -> tuple[float, float]:
    """Mean squared distance of the model's (key, value) from the teacher's: for the dataset's
    descriptions, to the teacher's own reading; for free-form ones, to the teacher's mean reading
    of the dataset's descriptions of the same triple."""
    texts, triples = dataset_descriptions(data)

    def encode(m, batch):
        feats, n = m.frozen_text_encoder().encode_arrays(batch)
        f = torch.from_numpy(feats).float()
        return f, torch.arange(f.shape[1])[None, :] < torch.from_numpy(n)[:, None]

    with torch.no_grad():
        tk, tv = reading(teacher, *encode(teacher, texts))
        mk, mv = reading(model, *encode(model, texts))
        own = float(((mk - tk) ** 2).sum(-1).mean() + ((mv - tv) ** 2).sum(-1).mean())
        other = training_texts([ALL_TRIPLES[t] for t in sorted(set(triples))], 2, 0, "free-form")
        errs = []
        for t, batch in other.items():
            mine = torch.from_numpy(triples == ALL_TRIPLES.index(t))
            k, v = reading(model, *encode(model, batch))
            errs.append(
                float(((k - tk[mine].mean(0)) ** 2).sum(-1).mean() + ((v - tv[mine].mean(0)) ** 2).sum(-1).mean())
            )
    return own, float(np.mean(errs))


def test_only_the_reader_learns_and_other_words_are_read_as_the_dataset_s(tiny_data, tmp_path):
    teacher, _ = load_checkpoint(shipped_checkpoint("emma"))
    data = SplitTokens(tiny_data, "train", None)
    result = tune_reader(run_args(tiny_data, tmp_path / "run", steps=48, eval_every=24), log=lambda *_: None)
    assert result["step"] == 48 and result["stopped"] == "steps"
    tuned, config = load_checkpoint(tmp_path / "run" / "last")
    assert config["config"]["text"]["max_tokens"] == 64 and config["reader_tuning"]["steps"] == 48
    before, after = dict(teacher.named_parameters()), dict(tuned.named_parameters())
    reader = ("text_encoder.", "reader.k", "reader.v", "reader.key_pool", "reader.value_pool")
    changed = {n for n in before if not torch.equal(before[n], after[n])}
    assert changed and all(n.startswith(reader) for n in changed), sorted(changed)
    # The decoder, the heads and the queries are the shipped model's, bit for bit.
    assert all(torch.equal(before[n], after[n]) for n in before if not n.startswith(reader))

    own_before, other_before = reading_error(teacher, teacher, data)
    own_after, other_after = reading_error(tuned, teacher, data)
    assert own_before == 0.0
    assert other_after < 0.8 * other_before, (other_before, other_after)
    # The dataset's own words stay read much as before: far closer than other words were.
    assert own_after < 0.2 * other_before, (own_after, other_before)


def test_a_run_resumes_exactly_and_a_model_without_a_reader_is_refused(tiny_data, tmp_path):
    straight = tmp_path / "straight"
    tune_reader(run_args(tiny_data, straight, steps=12, eval_every=6), log=lambda *_: None)
    chunked = tmp_path / "chunked"
    # A chunk ends by time (the schedule runs to --steps): this one after its first step.
    first = tune_reader(run_args(tiny_data, chunked, steps=12, eval_every=6, max_minutes=1e-9), log=lambda *_: None)
    assert (first["step"], first["stopped"]) == (1, "chunk time")
    result = tune_reader(run_args(tiny_data, chunked, steps=12, eval_every=6), log=lambda *_: None)
    assert result["step"] == 12
    a, _ = load_checkpoint(straight / "last")
    b, _ = load_checkpoint(chunked / "last")
    for (name, x), y in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(x, y), name

    def evaluations(run: Path) -> list[str]:
        return [line for line in (run / "metrics.jsonl").read_text().splitlines() if '"dev_total"' in line]

    assert evaluations(chunked)[1:] == evaluations(straight)  # the first chunk's own evaluation, then the same

    with pytest.raises(LwmError, match="only EMMA-LWM's reader can be tuned"):
        tune_reader(run_args(tiny_data, tmp_path / "obs", init=str(shipped_checkpoint("observational"))))

"""Teaching EMMA-LWM to read other words without changing what it imagines (`lwm tune-reader`).

EMMA-LWM reads a manual in two parts. The *reader* (the trainable text encoder over the frozen
encoder's token vectors, and the description attention's key and value pools and projections)
turns each description into a key, which decides the entity it is about, and a value, what that
entity does. The *decoder* adds what each entity reads to its id tokens and imagines. Fine-tuning
the whole model on other words (`lwm train --manual-mix`, docs/language.md) taught it to read them
but changed its imagination (most likely, not tested: a decoder shown text it cannot always read
learns to hedge).

Here only the reader learns and the decoder stays as shipped. The target is the model's own reading
of the dataset's descriptions: a description of the dataset should give the key and value it gave
before; a description in other words (the project's generator, the stress set's tuning bank) of a
training triple should give the mean key and value the model gives the dataset's descriptions of
that triple; and a splice of two of the dataset's descriptions (the start of one, the end of the
other) should be read as the model reads it. Within a triple the readings vary little (0.2% of
their spread across triples on the training split of data/human, measured), so the mean is the
triple's reading. The splices matter because NewAll's triples are new combinations: without them
the reader kept the training triples' readings but drifted on the dataset's descriptions of new
triples (docs/language.md). The decoder is never changed, so a manual read as before is imagined as
before.

A run directory holds `metrics.jsonl`, `last/` (weights and optimizer state, to resume a chunk
exactly) and `best/` (the checkpoint with the lowest mean NewAll-dev cross-entropy over the
dataset's descriptions and the other words'); running the same command again resumes.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..errors import LwmError
from ..messenger.constants import ALL_TRIPLES
from ..text.free_form import MIX_SOURCES, training_texts
from ..text.pools import DescriptionPools
from .base import WorldModel
from .checkpoint import load_checkpoint, publish, recover, save_checkpoint, write_checkpoint
from .frozen_text import FrozenTextEncoder
from .train import _cut_metrics, _load_train_state, _param_groups, _save_train_state, evaluate_loss, warmup_cosine_lr
from .training_data import SplitTokens, redraw_manuals


@dataclass
class ReaderTuningArgs:
    """Arguments of a reader-tuning run (recorded in its metrics and checkpoints)."""

    init: str = field(metadata={"help": "the EMMA-LWM checkpoint whose reader is tuned (its decoder is kept)"})
    data: str = field(metadata={"help": "dataset directory: its training split's descriptions are the targets"})
    out: str = field(metadata={"help": "run directory (last/, best/, metrics.jsonl); kept outside the repository"})
    steps: int = field(default=1500, metadata={"help": "optimizer steps in total (a resumed run continues to this)"})
    batch: int = field(default=64, metadata={"help": "descriptions of each kind (dataset, other words, splice) a step"})
    lr: float = field(default=3e-4, metadata={"help": "AdamW peak learning rate (warm-up, then cosine to 10%)"})
    warmup: int = field(default=100, metadata={"help": "linear warm-up steps"})
    weight_decay: float = field(default=0.01, metadata={"help": "AdamW weight decay of the Linear weights"})
    clip: float = field(default=10.0, metadata={"help": "gradient-norm clipping threshold"})
    max_tokens: int = field(
        default=64, metadata={"help": "encoder tokens read per description (long-winded ones run past the paper's 36)"}
    )
    mix_source: str = field(
        default="both", metadata={"help": "other words: both, generated (the generator's) or free-form (tuning bank)"}
    )
    mix_per_style: int = field(default=40, metadata={"help": "free-form descriptions per style and training triple"})
    token_drop: float = field(
        default=0.1, metadata={"help": "probability of hiding each token of an other-words description from the reader"}
    )
    splice: int = field(
        default=10_000,
        metadata={
            "help": "dataset-like descriptions made by joining the start of one training description to the end of "
            "another, to be read as the model reads them: new combinations of the dataset's words stay read as before"
        },
    )
    seed: int = field(default=0, metadata={"help": "seeds the free-form texts and the sampling of batches"})
    eval_every: int = field(default=500, metadata={"help": "steps between dev evaluations and checkpoints"})
    eval_episodes: int = field(default=300, metadata={"help": "NewAll-dev episodes of each dev evaluation"})
    threads: int | None = field(default=1, metadata={"help": "torch threads (None: PyTorch's)"})
    max_minutes: float | None = field(
        default=None, metadata={"help": "stop this chunk (after saving) when it has run this many wall-clock minutes"}
    )
    progress: bool = field(default=True, metadata={"help": "show a progress bar"})


def reading(model: WorldModel, features: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The key and value [N, W] the model reads from each of N descriptions alone (frozen-encoder
    token vectors [N, T, F] and mask [N, T]): what the description attention compares with each
    entity's query, and what the entity then adds to its id tokens."""
    tokens = model.text_encoder(features[:, None], mask[:, None])  # [N, 1, T, W]
    key, value = model.reader.read(tokens, mask[:, None])
    return key[:, 0], value[:, 0]


def _encode(encoder: FrozenTextEncoder, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
    feats, lengths = encoder.encode_arrays(texts)
    features = torch.from_numpy(feats).float()
    return features, torch.arange(features.shape[1])[None, :] < torch.from_numpy(lengths)[:, None]


@torch.no_grad()
def _readings(model: WorldModel, features: torch.Tensor, mask: torch.Tensor, chunk: int = 256) -> tuple:
    parts = [reading(model, features[i : i + chunk], mask[i : i + chunk]) for i in range(0, len(features), chunk)]
    return torch.cat([k for k, _ in parts]), torch.cat([v for _, v in parts])


def dataset_descriptions(data: SplitTokens) -> tuple[list[str], np.ndarray]:
    """The split's distinct descriptions and the triple index of each (as its manuals use it)."""
    triple_of: dict[int, int] = {}
    for e in range(len(data)):
        for k in range(3):
            triple_of.setdefault(int(data.manuals[e, k]), int(data.parses[e, k]))
    ids = sorted(triple_of)
    return [data.texts[i] for i in ids], np.array([triple_of[i] for i in ids], dtype=np.int64)


def spliced_descriptions(texts: list[str], n: int, rng: np.random.Generator) -> list[str]:
    """n distinct texts, each the first words of one of `texts` followed by the last words of
    another (at random cut points), none of them one of `texts`."""
    words = [t.split() for t in texts]
    seen, out = set(texts), []
    for _attempt in range(20 * n):
        if len(out) >= n:
            break
        a, b = rng.integers(len(words), size=2)
        joined = " ".join(words[a][: rng.integers(1, len(words[a]) + 1)] + words[b][rng.integers(len(words[b])) :])
        if joined not in seen:
            seen.add(joined)
            out.append(joined)
    return out


def _lr_at(step: int, args: ReaderTuningArgs) -> float:
    return warmup_cosine_lr(step, args.lr, args.warmup, args.steps)


def reader_parameters(model: WorldModel) -> list[nn.Parameter]:
    """The parameters that turn a description into its key and value: the text encoder and the
    description attention's pools and key/value projections. Not the query projection: it reads
    the decoder's id embeddings, and keys that match the old ones need the old queries."""
    params = list(model.text_encoder.parameters())
    return params + [p for name, p in model.reader.named_parameters() if not name.startswith("q.")]


def trainable_reader(model: WorldModel) -> list[nn.Parameter]:
    """Freeze everything but the reader (`reader_parameters`); returns its parameters."""
    model.requires_grad_(False)
    params = reader_parameters(model)
    for p in params:
        p.requires_grad_(True)
    return params


def tune_reader(args: ReaderTuningArgs, log=print) -> dict:
    """Run (or resume) a reader-tuning run; returns the final record."""
    if args.mix_source not in MIX_SOURCES:
        raise LwmError(f"unknown --mix-source {args.mix_source!r}; known: {', '.join(MIX_SOURCES)}")
    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    last, best_dir = out / "last", out / "best"
    recover(last)
    resuming = (last / "config.json").is_file() and (last / "train_state.json").is_file()
    teacher, init_config = load_checkpoint(args.init)
    if teacher.kind != "emma":
        raise LwmError(f"{args.init} holds a {teacher.kind!r} model; only EMMA-LWM's reader can be tuned")
    teacher.requires_grad_(False)
    model, _ = load_checkpoint(last if resuming else args.init, kind="emma")
    model.config = replace(model.config, text=replace(model.config.text, max_tokens=args.max_tokens))
    params = trainable_reader(model)
    model.train()

    # The targets: the teacher's reading of the dataset's descriptions, as it reads them.
    train_data = SplitTokens(args.data, "train", None)
    ds_texts, ds_triples = dataset_descriptions(train_data)
    triples = sorted(set(ds_triples.tolist()))
    spliced = spliced_descriptions(ds_texts, args.splice, np.random.default_rng([args.seed, 0x53504C]))
    keys, values = _readings(teacher, *_encode(teacher.frozen_text_encoder(), ds_texts))
    if spliced:
        splice_keys, splice_values = _readings(teacher, *_encode(teacher.frozen_text_encoder(), spliced))
    else:
        splice_keys, splice_values = keys[:0], values[:0]
    mean_key = torch.stack([keys[torch.from_numpy(ds_triples == t)].mean(0) for t in triples])
    mean_value = torch.stack([values[torch.from_numpy(ds_triples == t)].mean(0) for t in triples])
    row = {t: i for i, t in enumerate(triples)}
    # Losses are relative to each target's spread across descriptions, so keys and values weigh alike.
    key_scale = float(((keys - keys.mean(0)) ** 2).sum(-1).mean())
    value_scale = float(((values - values.mean(0)) ** 2).sum(-1).mean())
    spread = np.mean([float(((values[torch.from_numpy(ds_triples == t)] - mean_value[row[t]]) ** 2).sum(-1).mean())
                      for t in triples]) / value_scale  # fmt: skip

    other = training_texts([ALL_TRIPLES[t] for t in triples], args.mix_per_style, args.seed, args.mix_source)
    index = {tuple(t): i for i, t in enumerate(ALL_TRIPLES)}
    other_texts = [text for t, texts in other.items() for text in texts]
    other_rows = torch.tensor([row[index[tuple(t)]] for t, texts in other.items() for _ in texts])
    encoder = model.frozen_text_encoder()
    ds_features, ds_mask = _encode(encoder, ds_texts)
    other_features, other_mask = _encode(encoder, other_texts)
    splice_features, splice_mask = _encode(encoder, spliced) if spliced else (ds_features[:0], ds_mask[:0])
    log(
        f"reader tuning: {len(ds_texts)} dataset descriptions of {len(triples)} triples (within-triple spread "
        f"{spread:.2%} of the values'), {len(other_texts)} in other words ({args.mix_source}), {len(spliced)} spliced"
    )

    dev = SplitTokens(args.data, "newall-dev", encoder)
    dev_other = SplitTokens(args.data, "newall-dev", None)
    dev_triples = [ALL_TRIPLES[i] for i in np.unique(dev_other.parses)]
    dev_texts = training_texts(dev_triples, args.mix_per_style, args.seed, args.mix_source)
    pools = DescriptionPools({"newall-dev": {t: tuple(v) for t, v in dev_texts.items()}}, "other words")
    redraw_manuals(dev_other, pools, encoder, seed=args.seed)

    groups = [
        {**g, "params": [p for p in g["params"] if p.requires_grad]} for g in _param_groups(model, args.weight_decay)
    ]
    optimizer = torch.optim.AdamW(groups, lr=args.lr)
    rng = np.random.default_rng([args.seed, 0x52454144])
    torch.manual_seed(args.seed)  # the reader's dropout (a resumed run restores the generator's state)
    step, best = 0, float("inf")
    clock = {"wall_s": 0.0, "cpu_s": 0.0}
    if resuming:
        state = _load_train_state(last, optimizer, model)
        step, best, clock = state["step"], state["best_dev"], state["clock"]
        rng.bit_generator.state = state["rng"]
        _cut_metrics(out / "metrics.jsonl", step)
        log(f"resuming from step {step} (best dev {best:.4f})")
    out.mkdir(parents=True, exist_ok=True)
    meta = {
        "preset": init_config.get("preset"),  # the size preset of the model tuned: the decoder is its
        "reader_tuning": asdict(args),
        "init": str(args.init),
        "data": str(args.data),
    }
    began, cpu_began = time.perf_counter(), time.process_time()

    def elapsed() -> dict[str, float]:
        return {
            "wall_s": clock["wall_s"] + time.perf_counter() - began,
            "cpu_s": clock["cpu_s"] + time.process_time() - cpu_began,
        }

    def record(entry: dict) -> None:
        with open(out / "metrics.jsonl", "a") as f:
            f.write(json.dumps({**entry, "seed": args.seed}) + "\n")

    bar = None
    if args.progress:
        from tqdm import tqdm

        bar = tqdm(total=args.steps, initial=step, unit="step", desc="tune reader")

    def checkpoint() -> None:
        """Evaluate on NewAll-dev, keep the best, and swap in last/ (weights and optimizer state of
        one step, written together)."""
        nonlocal best
        model.eval()
        ce = evaluate_loss(model, dev, limit=args.eval_episodes)["total"]
        ce_other = evaluate_loss(model, dev_other, limit=args.eval_episodes)["total"]
        model.train()
        selection = (ce + ce_other) / 2
        record({"step": step, "dev_total": ce, "dev_other_total": ce_other, "dev_selection": selection})
        if bar:
            bar.write(f"step {step}: newall-dev CE {ce:.4f} (dataset's words), {ce_other:.4f} (other words)")
        extra = {**meta, "steps": step, "dev": {"newall-dev": {"total": ce, "other_words_total": ce_other}}}
        if selection < best:
            best = selection
            save_checkpoint(model, best_dir, extra)

        def fill(d: Path) -> None:
            write_checkpoint(model, d, extra)
            _save_train_state(d, optimizer, model, step, rng, best, elapsed())

        publish(last, fill)

    window: list[tuple[float, float]] = []
    stopped = "steps"
    while step < args.steps:
        for g in optimizer.param_groups:
            g["lr"] = _lr_at(step, args)
        i = torch.from_numpy(rng.integers(len(ds_texts), size=args.batch))
        j = torch.from_numpy(rng.integers(len(other_texts), size=args.batch))
        hide = torch.from_numpy(rng.random((args.batch, other_mask.shape[1])) < args.token_drop)
        hide[:, 0] = False  # a description keeps at least its first token
        q = torch.from_numpy(rng.integers(max(1, len(spliced)), size=args.batch if spliced else 0))
        features = torch.cat([ds_features[i], other_features[j], splice_features[q]])
        mask = torch.cat([ds_mask[i], other_mask[j] & ~hide, splice_mask[q]])
        width = int(mask.sum(-1).max())
        key, value = reading(model, features[:, :width], mask[:, :width])
        want_key = torch.cat([keys[i], mean_key[other_rows[j]], splice_keys[q]])
        want_value = torch.cat([values[i], mean_value[other_rows[j]], splice_values[q]])
        err = ((key - want_key) ** 2).sum(-1) / key_scale + ((value - want_value) ** 2).sum(-1) / value_scale
        loss = err.mean()
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(params, args.clip)
        optimizer.step()
        step += 1
        done = err.detach()
        window.append((float(done[: args.batch].mean()), float(done[args.batch : 2 * args.batch].mean())))
        if bar:
            bar.update(1)
        if step % 50 == 0:
            ds_err, other_err = np.mean(window, axis=0)
            record({"step": step, "dataset_error": ds_err, "other_error": other_err, "lr": _lr_at(step - 1, args),
                    "elapsed_s": round(elapsed()["wall_s"], 1), "cpu_s": round(elapsed()["cpu_s"], 1)})  # fmt: skip
            window = []
        out_of_time = args.max_minutes is not None and time.perf_counter() - began > 60 * args.max_minutes
        if step % args.eval_every == 0 or step == args.steps or out_of_time:
            checkpoint()
        if out_of_time:
            stopped = "chunk time"
            break
    if bar:
        bar.close()
    return {"step": step, "best_dev": best, "stopped": stopped, "out": str(out), **elapsed()}


__all__ = [
    "ReaderTuningArgs",
    "dataset_descriptions",
    "reading",
    "spliced_descriptions",
    "trainable_reader",
    "tune_reader",
]

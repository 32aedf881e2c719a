"""Training of the world models (`lwm train`).

The paper's recipe by default: AdamW lr 1e-4, weight decay 0.01 on Linear weights only, gradient
norm clipped at 10, batches of 32 segments starting at a random step of a random episode, first
block context only, padding masked; the best checkpoint by NewAll-dev total loss.

A run directory holds `metrics.jsonl`, `last/` (weights + optimizer state, for resuming) and
`best/` (the best dev checkpoint). Running the same command again resumes from `last/` exactly
(weights, optimizer moments, both random generators, the metrics log cut back to the resumed step,
and the run's accumulated wall-clock and CPU time), so a long run can be trained in chunks:
`--max-minutes` bounds one chunk, `--cpu-budget-minutes` the whole run.
Under `torchrun` it trains with DistributedDataParallel (gloo on CPU, nccl on GPUs); each rank
samples its own batches and rank 0 evaluates and writes.
"""

from __future__ import annotations

import gc
import json
import math
import os
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from safetensors.torch import load_file, save_file
from torch import nn

from ..errors import LwmError
from ..messenger.constants import ALL_TRIPLES
from ..text.free_form import training_texts
from ..text.pools import DescriptionPools
from .base import LossOutput, WorldModel, event_steps, losses, target_blocks
from .checkpoint import load_checkpoint, publish, recover, save_checkpoint, write_checkpoint
from .registry import PRESETS, build_model
from .training_data import SplitTokens, redraw_manuals


@dataclass
class TrainArgs:
    """Arguments of a training run (all recorded in the run's metrics and checkpoints)."""

    data: str = field(metadata={"help": "dataset directory from `lwm data generate`"})
    out: str = field(metadata={"help": "run directory (checkpoints last/ and best/, metrics.jsonl)"})
    kind: str = field(default="emma", metadata={"help": "world model kind"})
    preset: str = field(default="paper", metadata={"help": "model size preset"})
    steps: int = field(default=100_000, metadata={"help": "optimizer steps in total (a resumed run continues to this)"})
    batch: int = field(default=32, metadata={"help": "training segments (of random episodes) per optimizer step"})
    lr: float = field(default=1e-4, metadata={"help": "AdamW learning rate"})
    warmup: int = field(default=0, metadata={"help": "linear warm-up steps (0: the paper's constant lr)"})
    cosine: bool = field(
        default=False, metadata={"help": "cosine decay to 10% of lr after warm-up (a budget-run option)"}
    )
    weight_decay: float = field(default=0.01, metadata={"help": "AdamW weight decay of the Linear weights"})
    clip: float = field(default=10.0, metadata={"help": "gradient-norm clipping threshold"})
    seed: int = field(default=0, metadata={"help": "seeds the initialization and the sampling of batches"})
    eval_every: int = field(default=1000, metadata={"help": "steps between dev evaluations and checkpoints"})
    eval_split: str = field(default="newall-dev", metadata={"help": "split of the dev evaluation"})
    eval_episodes: int | None = field(
        default=None, metadata={"help": "episodes of each dev evaluation (default: the whole eval split)"}
    )
    bf16: bool = field(default=False, metadata={"help": "bf16 autocast on CPU (speed option)"})
    parts: int = field(
        default=4,
        metadata={
            "help": "compute each batch as this many groups of segments of similar length, each padded to its own "
            "longest (the same loss and gradient as one padded batch, less padding; 1 under torchrun)"
        },
    )
    attn_dropout: float | None = field(
        default=None,
        metadata={"help": "attention dropout (default: the preset's, paper 0.1); 0 enables fused attention"},
    )
    kv_heads: int | None = field(
        default=None,
        metadata={
            "help": "key/value heads (default: the preset's, small: 1, multi-query); as many as heads: multi-head"
        },
    )
    init: str | None = field(
        default=None,
        metadata={"help": "start from this checkpoint's weights (fine-tuning; a resumed run ignores it)"},
    )
    max_tokens: int | None = field(
        default=None,
        metadata={"help": "encoder tokens kept per description (default: the preset's or --init's, paper 36)"},
    )
    manual_mix: float = field(
        default=0.0,
        metadata={
            "help": "probability that a training description is replaced by another of its triple: generated or "
            "free-form (lwm_models/text/free_form.py, never the stress set's held-out bank); the best checkpoint "
            "is then chosen on the mean of the dev loss with the dataset's text and with such text"
        },
    )
    mix_source: str = field(
        default="both",
        metadata={"help": "what --manual-mix draws from: both, generated (the generator's) or free-form (tuning bank)"},
    )
    mix_per_style: int = field(
        default=12, metadata={"help": "free-form descriptions per style and triple in the --manual-mix pool"}
    )
    distill: str | None = field(
        default=None,
        metadata={
            "help": "a teacher checkpoint (e.g. the one --init names): the loss adds the KL divergence from the "
            "teacher's predictions, given each episode's own (dataset) descriptions, to this model's, given the "
            "descriptions it is trained on (mixed in by --manual-mix): it learns to read other words as the "
            "teacher reads the dataset's, and keeps the teacher's dynamics where the text does not matter"
        },
    )
    hedge_practice: float = field(
        default=0.0,
        metadata={
            "help": "emma-hedged only: the share of training descriptions read as its hedge reads them (the mean "
            "prototype of the triples the words allow, a field left open at random), so that the decoder learns to "
            "imagine from a hedged reading; the reader is frozen"
        },
    )
    distill_weight: float = field(default=1.0, metadata={"help": "weight of the --distill term in the loss"})
    event_weight: float = field(
        default=1.0,
        metadata={
            "help": "weight of the target tokens of steps with a reward or the end, against 1 for the others: a "
            "contact's outcome follows from the manual's roles, and such steps are about one in fifteen"
        },
    )
    select: str = field(
        default="loss",
        metadata={
            "help": "what chooses the best checkpoint: 'loss' (the dev loss) or 'imagined-reward' (the imagined "
            "reward precision on the dev split, raw sampling, mean over the dataset's text and the --manual-mix "
            "text): a model can lower its loss while its imagination rewards in the wrong places"
        },
    )
    select_episodes: int = field(default=300, metadata={"help": "dev episodes imagined for --select imagined-reward"})
    threads: int | None = field(default=None, metadata={"help": "torch threads (default: PyTorch's)"})
    tensorboard: bool = field(default=False, metadata={"help": "also write TensorBoard logs to RUN/tb"})
    progress: bool = field(default=True, metadata={"help": "show a progress bar"})
    max_minutes: float | None = field(
        default=None,
        metadata={"help": "stop this chunk (after saving) when it has run this many wall-clock minutes"},
    )
    cpu_budget_minutes: float | None = field(
        default=None, metadata={"help": "stop the run when its CPU time over all chunks reaches this many minutes"}
    )


def _param_groups(model: nn.Module, weight_decay: float) -> list[dict]:
    """Weight decay on Linear weights only (not biases, LayerNorms or embeddings)."""
    decay, no_decay = [], []
    for module in model.modules():
        for name, p in module.named_parameters(recurse=False):
            (decay if isinstance(module, nn.Linear) and name == "weight" else no_decay).append(p)
    return [{"params": decay, "weight_decay": weight_decay}, {"params": no_decay, "weight_decay": 0.0}]


def warmup_cosine_lr(step: int, lr: float, warmup: int, steps: int, cosine: bool = True) -> float:
    """The learning rate at `step`: linear warm-up over `warmup` steps, then (with `cosine`) a cosine
    decay to 10% of `lr` at `steps`, or else `lr` throughout."""
    if warmup and step < warmup:
        return lr * (step + 1) / warmup
    if cosine:
        progress = (step - warmup) / max(1, steps - warmup)
        return lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, progress))))
    return lr


def _lr_at(step: int, args: TrainArgs) -> float:
    return warmup_cosine_lr(step, args.lr, args.warmup, args.steps, args.cosine)


def _save_train_state(
    path: Path,
    optimizer: torch.optim.Optimizer,
    model: nn.Module,
    step: int,
    rng: np.random.Generator,
    best: float,
    clock: dict[str, float],
) -> None:
    """Optimizer moments by parameter name, in safetensors (no pickles), plus JSON bookkeeping,
    into the run's next `last/` while it is being built."""
    names = {id(p): n for n, p in model.named_parameters()}
    tensors = {}
    for group in optimizer.param_groups:
        for p in group["params"]:
            state = optimizer.state.get(p)
            if state:
                n = names[id(p)]
                tensors[f"exp_avg/{n}"] = state["exp_avg"].contiguous()
                tensors[f"exp_avg_sq/{n}"] = state["exp_avg_sq"].contiguous()
                tensors[f"step/{n}"] = torch.as_tensor(state["step"], dtype=torch.float64).reshape(1)
    save_file(tensors, str(path / "optimizer.safetensors"))
    state = {
        "step": step,
        "rng": rng.bit_generator.state,
        "best_dev": best,
        "clock": clock,  # the run's wall-clock and CPU seconds over all chunks so far
        "torch_rng": torch.get_rng_state().tolist(),
    }
    (path / "train_state.json").write_text(json.dumps(state))


def _split_triples(data: SplitTokens) -> list:
    return [ALL_TRIPLES[i] for i in np.unique(data.parses)]


def _mix_texts(data: SplitTokens, args: TrainArgs) -> dict:
    return training_texts(_split_triples(data), per_style=args.mix_per_style, seed=args.seed, source=args.mix_source)


def mix_pools(data: SplitTokens, args: TrainArgs) -> DescriptionPools:
    """The dev split's manuals re-drawn from the training mix's kind of text (for its own triples)."""
    texts = _mix_texts(data, args)
    return DescriptionPools({data.split: {t: tuple(v) for t, v in texts.items()}}, "manual-mix")


def _cut_metrics(path: Path, step: int) -> None:
    """Drop the log lines written after the checkpoint a run resumes from: they are trained again."""
    if not path.is_file():
        return
    kept = []
    for line in path.read_text().splitlines():
        try:
            if json.loads(line)["step"] <= step:
                kept.append(line)
        except (json.JSONDecodeError, KeyError, TypeError):
            continue  # a torn last line of a killed run
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("".join(line + "\n" for line in kept))
    os.replace(tmp, path)


def _load_train_state(path: Path, optimizer: torch.optim.Optimizer, model: nn.Module) -> dict:
    tensors = load_file(str(path / "optimizer.safetensors"))
    params = dict(model.named_parameters())
    for n, p in params.items():
        if f"exp_avg/{n}" in tensors:
            optimizer.state[p] = {
                "exp_avg": tensors[f"exp_avg/{n}"],
                "exp_avg_sq": tensors[f"exp_avg_sq/{n}"],
                "step": torch.tensor(float(tensors[f"step/{n}"][0])),
            }
    state = json.loads((path / "train_state.json").read_text())
    torch.set_rng_state(torch.tensor(state["torch_rng"], dtype=torch.uint8))
    return state


SELECTIONS = ("loss", "imagined-reward")


def imagined_precision(
    model: WorldModel, dev: SplitTokens, mixed: SplitTokens | None, episodes: int, seed: int = 0
) -> dict:
    """Imagined reward and termination precision on the dev split (Table 2, raw sampling), and the
    selection key they give: the negated mean reward precision, so that lower is better as for a loss."""
    from .evaluate import imagination_metrics

    out, precisions = {}, []
    for name, data in (("", dev), ("mixed_", mixed)):
        if data is None:
            continue
        m = imagination_metrics(model, data, episodes, seed=seed)
        out[f"{name}reward_precision"] = m.reward_precision
        out[f"{name}termination_precision"] = m.termination_precision
        # what tells a model that rewards too often from one whose entities drift (docs/language.md)
        out[f"{name}reward_recall"] = m.reward_recall
        out[f"{name}delta_dist"] = m.delta_dist
        precisions.append(m.reward_precision)
    out["selection"] = -float(np.mean(precisions))
    return out


def weighted_objective(
    model: WorldModel, teacher: WorldModel | None, parts: list[tuple], event_weight: float, distill_weight: float
) -> tuple[LossOutput, torch.Tensor, torch.Tensor | None]:
    """The batch's plain cross-entropy (for the log), the loss to minimise and the distillation term.

    Every target token of a step where something happens (`event_steps`) weighs `event_weight`,
    the others 1, in weighted means per token kind. With a teacher, each token also adds
    `distill_weight` x KL(teacher given the episode's own descriptions || model given the
    trained-on ones) in the same weighted means. Parts are (tokens, lengths, manual[, own manual])."""
    outs = []
    sums: dict[str, torch.Tensor] = {}
    norms: dict[str, torch.Tensor] = {}
    kl_sums: dict[str, torch.Tensor] = {}
    for part in parts:
        tokens, lengths, manual = part[:3]
        mine = model.predictions(tokens, lengths, manual)
        outs.append(losses(mine))
        wanted = None
        if teacher is not None:
            with torch.no_grad():
                wanted = teacher.predictions(tokens, lengths, part[3])
        events = event_steps(tokens)
        for name, block in target_blocks(tokens.shape[1]).items():
            logits, target, mask = mine[name]
            weight = torch.where(events[:, block], event_weight, 1.0) * mask
            ce = F.cross_entropy(logits.transpose(1, 2), target, reduction="none")
            sums[name] = sums.get(name, 0) + (ce * weight).sum()
            norms[name] = norms.get(name, 0) + weight.sum()
            if wanted is not None:
                target_logp = F.log_softmax(wanted[name][0], dim=-1)
                kl = (target_logp.exp() * (target_logp - F.log_softmax(logits, dim=-1))).sum(-1)
                kl_sums[name] = kl_sums.get(name, 0) + (kl * weight).sum()
    loss = sum(sums[k] / norms[k].clamp(min=1) for k in sums)
    kl_term = sum(kl_sums[k] / norms[k].clamp(min=1) for k in kl_sums) if kl_sums else None
    if kl_term is not None:
        loss = loss + distill_weight * kl_term
    return batch_loss(outs), loss, kl_term


def batch_loss(outs: list[LossOutput]) -> LossOutput:
    """The loss of a batch computed in parts: each of obs, reward and done is its summed
    cross-entropy over all parts divided by its token count over all parts, as if the batch had
    been one forward (so the gradient is the same)."""
    if len(outs) == 1:
        return outs[0]
    sums = {k: sum(o.sums[k] for o in outs) for k in ("obs", "reward", "done")}
    counts = {k: sum(o.counts[k] for o in outs) for k in sums}
    means = {k: sums[k] / counts[k].clamp(min=1) for k in sums}
    total = means["obs"] + means["reward"] + means["done"]
    return LossOutput(total, means["obs"], means["reward"], means["done"], sums, counts)


@torch.no_grad()
def evaluate_loss(
    model: WorldModel, data: SplitTokens, batch: int = 64, limit: int | None = None, bf16: bool = False
) -> dict[str, float]:
    """Teacher-forced cross-entropy over whole episodes: exact per-token means of obs, reward and
    done, and their total."""
    was_training = model.training
    model.eval()
    sums = {"obs": 0.0, "reward": 0.0, "done": 0.0}
    counts = dict.fromkeys(sums, 0)
    for tokens, lengths, manual in data.full_episodes(batch, limit):
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            out = model(tokens, lengths, manual)
        for k in sums:
            sums[k] += float(out.sums[k])
            counts[k] += int(out.counts[k])
    model.train(was_training)
    result = {k: sums[k] / max(1, counts[k]) for k in sums}
    result["total"] = result["obs"] + result["reward"] + result["done"]
    return result


def train(args: TrainArgs, log=print) -> dict:
    """Run (or resume) training; returns the final record."""
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    rank = 0
    if distributed:
        backend = "nccl" if torch.cuda.is_available() else "gloo"
        dist.init_process_group(backend)
        rank = dist.get_rank()
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.preset not in PRESETS:
        raise LwmError(f"unknown preset {args.preset!r}; known: {', '.join(PRESETS)}")
    if (args.distill or args.event_weight != 1.0) and distributed:
        raise LwmError("--distill and --event-weight are not supported under torchrun (they bypass DDP's forward)")
    if args.select not in SELECTIONS:
        raise LwmError(f"unknown --select {args.select!r}; known: {', '.join(SELECTIONS)}")
    out = Path(args.out)
    last, best_dir = out / "last", out / "best"

    config = PRESETS[args.preset]
    overrides = {k: v for k, v in (("attn_dropout", args.attn_dropout), ("kv_heads", args.kv_heads)) if v is not None}
    if overrides:
        config = type(config)(type(config.decoder)(**{**asdict(config.decoder), **overrides}), config.text)
    recover(last)
    resuming = (last / "config.json").is_file() and (last / "train_state.json").is_file()
    made: dict = {}  # the starting checkpoint's config: how its fitted buffers were made (a hedged model's)
    if resuming:
        model, made = load_checkpoint(last, kind=args.kind)
        if made.get("preset") != args.preset:
            raise LwmError(f"{last} was trained with preset {made.get('preset')!r}, not {args.preset!r}")
    elif args.init:
        model, made = load_checkpoint(args.init, kind=args.kind)
    else:
        torch.manual_seed(args.seed)
        model = build_model(args.kind, config)
    if args.hedge_practice > 0:
        if not hasattr(model, "practise_hedges"):
            raise LwmError(f"--hedge-practice needs a hedged world model (kind emma-hedged), not {args.kind!r}")
        model.practise_hedges(args.hedge_practice)
    if args.max_tokens is not None:
        model.config = replace(model.config, text=replace(model.config.text, max_tokens=args.max_tokens))
    model.train()

    encoder = model.frozen_text_encoder()
    router = model.route
    train_data = SplitTokens(args.data, "train", encoder, router)
    dev_data = SplitTokens(args.data, args.eval_split, encoder, router) if rank == 0 else None
    dev_mixed = None
    if args.manual_mix > 0:
        train_data.mix_manuals(_mix_texts(train_data, args), args.manual_mix, encoder)
        if rank == 0:
            dev_mixed = SplitTokens(args.data, args.eval_split, encoder, router)
            redraw_manuals(dev_mixed, mix_pools(dev_mixed, args), encoder, seed=args.seed)

    teacher = None
    if args.distill:
        teacher, _ = load_checkpoint(args.distill, kind=args.kind)
        teacher.eval().requires_grad_(False)
    optimizer = torch.optim.AdamW(_param_groups(model, args.weight_decay), lr=args.lr, betas=(0.9, 0.999))
    rng = np.random.default_rng([args.seed, rank])
    step, best = 0, float("inf")
    clock = {"wall_s": 0.0, "cpu_s": 0.0}
    if resuming:
        state = _load_train_state(last, optimizer, model)
        step, best = state["step"], state["best_dev"]
        clock = state.get("clock", clock)
        rng.bit_generator.state = state["rng"]
        if rank == 0:
            _cut_metrics(out / "metrics.jsonl", step)
            log(
                f"resuming {args.kind} from step {step} (best dev {best:.4f}; "
                f"{clock['wall_s'] / 60:.1f} min, {clock['cpu_s'] / 60:.1f} CPU-min so far)"
            )
    net: nn.Module = nn.parallel.DistributedDataParallel(model) if distributed else model

    meta = {
        "preset": args.preset,
        "train_args": asdict(args),
        "data": str(args.data),
        "text_encoder": encoder.name if encoder else None,
        **({"hedged_reading": made["hedged_reading"]} if "hedged_reading" in made else {}),
    }
    metrics_path = out / "metrics.jsonl"
    writer = None
    if rank == 0:
        out.mkdir(parents=True, exist_ok=True)
        if args.tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter

                writer = SummaryWriter(str(out / "tb"))
            except ImportError:
                log("tensorboard is not installed; metrics go to metrics.jsonl only")

    def record(entry: dict) -> None:
        if rank != 0:
            return
        with open(metrics_path, "a") as f:
            f.write(json.dumps(entry) + "\n")
        if writer:
            for k, v in entry.items():
                if isinstance(v, (int, float)) and k != "step":
                    writer.add_scalar(k, v, entry["step"])

    def checkpoint(dev: dict | None) -> None:
        nonlocal best
        if rank != 0:
            return
        extra = {**meta, "steps": step, "seed": args.seed}
        if dev is not None:
            extra["dev"] = {args.eval_split: dev}
            if dev.get("selection", dev["total"]) < best:
                best = dev.get("selection", dev["total"])
                save_checkpoint(model, best_dir, extra)

        # Weights and optimizer state must come from the same step, even if the process is killed
        # while writing: both go into one directory that is swapped in whole.
        def fill(d: Path) -> None:
            write_checkpoint(model, d, extra)
            _save_train_state(d, optimizer, model, step, rng, best, elapsed())

        publish(last, fill)

    bar = None
    if rank == 0 and args.progress:
        from tqdm import tqdm

        bar = tqdm(total=args.steps, initial=step, unit="step", desc=f"train {args.kind}")
    began = time.perf_counter()
    cpu_began = time.process_time()  # this process's CPU time: comparable across runs sharing a machine

    def elapsed() -> dict[str, float]:
        """The run's time over all its chunks (this chunk's plus the resumed state's)."""
        return {
            "wall_s": clock["wall_s"] + time.perf_counter() - began,
            "cpu_s": clock["cpu_s"] + time.process_time() - cpu_began,
        }

    window: list[float] = []
    stop_reason = "steps"
    if args.cpu_budget_minutes is not None and clock["cpu_s"] >= 60 * args.cpu_budget_minutes:
        step_limit, stop_reason = step, "CPU budget"  # spent by earlier chunks: nothing left to train
    else:
        step_limit = args.steps
    while step < step_limit:
        lr = _lr_at(step, args)
        for g in optimizer.param_groups:
            g["lr"] = lr
        # DistributedDataParallel expects one forward per backward: one part there.
        parts_n = 1 if distributed else args.parts
        parts = train_data.sample_parts(rng, args.batch, parts_n, own_manuals=teacher is not None)
        with torch.autocast("cpu", dtype=torch.bfloat16, enabled=args.bf16):
            if teacher is None and args.event_weight == 1.0:
                out_, kl = batch_loss([net(*part) for part in parts]), None
                loss = out_.loss
            else:
                out_, loss, kl = weighted_objective(model, teacher, parts, args.event_weight, args.distill_weight)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = float(nn.utils.clip_grad_norm_(model.parameters(), args.clip))
        optimizer.step()
        step += 1
        window.append(out_.loss.item())
        if bar:
            bar.update(1)
            bar.set_postfix(loss=f"{np.mean(window[-50:]):.3f}")
        if step % 50 == 0:
            now = elapsed()
            record(
                {
                    "step": step,
                    "loss": float(np.mean(window)),
                    "obs": out_.obs.item(),
                    "reward": out_.reward.item(),
                    "done": out_.done.item(),
                    **({"distill_kl": kl.item()} if kl is not None else {}),
                    "lr": lr,
                    "grad_norm": grad_norm,
                    "elapsed_s": round(now["wall_s"], 1),
                    "cpu_s": round(now["cpu_s"], 1),
                    "seed": args.seed,
                }
            )
            window = []
        chunk_over = args.max_minutes is not None and time.perf_counter() - began > 60 * args.max_minutes
        budget_spent = args.cpu_budget_minutes is not None and elapsed()["cpu_s"] > 60 * args.cpu_budget_minutes
        out_of_time = chunk_over or budget_spent
        if step % args.eval_every == 0 or step == args.steps or out_of_time:
            dev = None
            if rank == 0:
                eval_began = time.perf_counter()
                began_at = elapsed()
                dev = evaluate_loss(model, dev_data, limit=args.eval_episodes, bf16=args.bf16)
                if dev_mixed is not None:
                    mixed = evaluate_loss(model, dev_mixed, limit=args.eval_episodes, bf16=args.bf16)
                    dev["mixed_total"] = mixed["total"]
                    dev["selection"] = (dev["total"] + mixed["total"]) / 2
                if args.select == "imagined-reward":
                    dev.update(imagined_precision(model, dev_data, dev_mixed, args.select_episodes, args.seed))
                    model.train()
                record(
                    {
                        "step": step,
                        **{f"dev_{k}": v for k, v in dev.items()},
                        # the run's time when this evaluation began
                        "elapsed_s": round(began_at["wall_s"], 1),
                        "cpu_s": round(began_at["cpu_s"], 1),
                        "eval_s": round(time.perf_counter() - eval_began, 1),
                        "seed": args.seed,
                    }
                )
                if bar:
                    mixed = f", other words {dev['mixed_total']:.4f}" if "mixed_total" in dev else ""
                    bar.write(f"step {step}: {args.eval_split} total {dev['total']:.4f} (obs {dev['obs']:.4f}){mixed}")
            checkpoint(dev)
        if out_of_time:
            stop_reason = "CPU budget" if budget_spent else "chunk time"
            break
    if bar:
        bar.close()
    if distributed:
        dist.barrier()
        # DDP's reducer keeps the process group alive; drop it while the interpreter is whole so
        # that gloo's threads are not torn down during interpreter finalization (a rank aborted
        # once at exit with "terminate called without an active exception").
        del net
        gc.collect()
        dist.destroy_process_group()
    return {"step": step, "best_dev": best, "stopped": stop_reason, "out": str(out), **elapsed()}

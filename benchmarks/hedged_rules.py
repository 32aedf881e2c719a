"""How a hedged world model's reading rules compare (issue 30), on data they may be chosen on: the
dev part of the stress set and a dev split, never the held-out part or a test split.

For each rule, the teacher-forced cross-entropy (`evaluate_loss`, as `lwm eval`) with the dataset's
descriptions and with each style of the stress set's dev part (`--part written`: its hand-written
second dev part; manuals re-drawn for the same triples), and Table 2's imagined reward / termination
precision (raw sampling) with the dataset's text (`--imagine-styles`: with each dev style too).
Rules: "mean" (EMMA-LWM only: a description the words do not agree with is read as the mean
prototype of what they allow) and "mixture:W:Q" (every reading the words allow, the model's own with
prior W and the model's entity, where the words name another, with prior Q; "mixture:W:Q:D" keeps
the triples one decided field away from the words at prior D, and "mixture:W:Q:D:N" keeps a
manual's N likeliest readings instead of `MAX_READINGS`, "mixture:W:Q:D:N:K" only K of them after
the first `PRUNE_STEPS` steps, the likeliest given those; `hedged_reading.readings`), either
with "+ground" (the words' entities grounded on each episode's board first); `--stand-quantiles`
runs each rule with each stand distance. Observational, which reads no text, is the line to beat.
Every figure comes from this one run, so the rules are compared on the same episodes and code.

    flock /tmp/lwm-heavy.lock .venv/bin/python benchmarks/hedged_rules.py --data data/human \\
        --rules mean mixture:0.8:0 mixture:0.8:0.15 --episodes 100 --imagination-episodes 200
    flock /tmp/lwm-heavy.lock .venv/bin/python benchmarks/hedged_rules.py --data data/human \\
        --checkpoint lwm_models/checkpoints/gpthard-hedged --rules mixture:0.8:0 --stand-quantiles 0.5 0
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.errors import LwmError  # noqa: E402
from lwm_models.text.stress import stress_pools, stress_styles  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint  # noqa: E402
from lwm_models.world.evaluate import imagination_metrics  # noqa: E402
from lwm_models.world.hedged_reading import MAX_READINGS, HedgedReading  # noqa: E402
from lwm_models.world.reader_tuning import dataset_descriptions  # noqa: E402
from lwm_models.world.train import evaluate_loss  # noqa: E402
from lwm_models.world.training_data import SplitTokens, redraw_manuals  # noqa: E402

CHECKPOINTS = ROOT / "lwm_models" / "checkpoints"


def set_rule(model, rule: str) -> None:
    """Read with `rule`: "mean", or "mixture:W:Q:D:N:K" (W the prior of the model's own reading, default
    0.8; Q that of its entity where the words name another, default 0.15; D that of the triples one
    decided field away from the words, default 0; N the readings of a manual kept, default
    `MAX_READINGS`; K of them those predicting after the first `PRUNE_STEPS` steps, default 0: all);
    "+ground" after either
    grounds the words' entities on each episode's board first (`hedged_reading.ground_words`)."""
    rule, plus, extra = rule.partition("+")
    if plus and extra != "ground":
        raise LwmError(f"unknown rule {rule + plus + extra!r}: the one addition is +ground")
    model.ground = bool(plus)
    name, *numbers = rule.split(":")
    if name == "mean" and not numbers:
        if not hasattr(model, "_hedged"):
            raise LwmError(f"a {model.kind} model has no mean-prototype rule; give mixture:W[:Q]")
        model.mixture = False
        return
    if name != "mixture" or len(numbers) > 5:
        raise LwmError(f"unknown rule {rule!r}: give mean or mixture:W[:Q[:D[:N[:K]]]] (priors, 0-1; readings)")
    try:
        weights = [float(x) for x in numbers]
    except ValueError:
        raise LwmError(f"mixture:W:Q needs numbers, got {rule!r}") from None
    own, other, doubt, most, keep = (weights + [0.8, 0.15, 0.0, MAX_READINGS, 0][len(weights) :])[:5]
    if not (0.0 < own <= 1.0 and 0.0 <= other < 1.0 and 0.0 <= doubt < 1.0):
        raise LwmError(f"the priors must be in (0, 1], [0, 1) and [0, 1), got {own}, {other} and {doubt}")
    if most < 1 or most != int(most) or keep < 0 or keep != int(keep):
        raise LwmError(f"the readings kept must be whole numbers (N 1 or more, K 0 or more), got {most} and {keep}")
    model.mixture, model.own_weight, model.other_identity, model.doubt = True, own, other, doubt
    model.max_readings, model.keep_readings = int(most), int(keep)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="dataset directory (lwm data generate)")
    parser.add_argument(
        "--checkpoint", type=Path, default=CHECKPOINTS / "emma-lwm-hedged", help="a hedged EMMA-LWM or GPTHard"
    )
    parser.add_argument("--split", default="newall-dev", help="a dev split")
    parser.add_argument(
        "--part",
        choices=("dev", "written"),
        default="dev",
        help="the stress set's part the styles come from (written: the hand-written second dev part)",
    )
    parser.add_argument("--rules", nargs="+", default=["mean", "mixture:0.8:0", "mixture:0.8:0.15"])
    parser.add_argument("--episodes", type=int, default=100, help="episodes of the cross-entropy (evenly spaced)")
    parser.add_argument("--imagination-episodes", type=int, default=200, help="0: no imagination")
    parser.add_argument(
        "--imagine-styles", action="store_true", help="imagined precision with each dev style too, not only the dataset"
    )
    parser.add_argument(
        "--stand-quantiles",
        type=float,
        nargs="+",
        default=None,
        help="also vary the stand distance: each rule with each quantile of the training descriptions' "
        "distances (HedgedReading.fit_stand_distance; 0: none stands); default: the checkpoint's",
    )
    parser.add_argument("--seed", type=int, default=0, help="manual re-drawing and imagination seed")
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--out", type=Path, help="write the figures as JSON")
    args = parser.parse_args(argv)
    if args.split.endswith("-test"):
        print("hedged_rules: rules are chosen on dev splits; the test splits are for reporting", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    began = time.perf_counter()
    try:
        model, _ = load_checkpoint(args.checkpoint)
        if not isinstance(model, HedgedReading):
            raise LwmError(f"{args.checkpoint} holds a {model.kind!r} model, not a hedged one")
        for rule in args.rules:
            set_rule(model, rule)
        train_texts = None
        if args.stand_quantiles:
            train_texts, _ = dataset_descriptions(SplitTokens(args.data, "train", None, None))
        observational, _ = load_checkpoint(CHECKPOINTS / "observational")
        encoder = model.frozen_text_encoder()
        sources = {"dataset": SplitTokens(args.data, args.split, encoder, model.route)}
        for style in stress_styles():
            data = SplitTokens(args.data, args.split, None, model.route)
            redraw_manuals(data, stress_pools(style, args.part), encoder, args.seed)
            sources[f"{args.part}:{style}"] = data
    except (LwmError, OSError) as exc:
        print(f"hedged_rules: {exc}", file=sys.stderr)
        return 2
    blind = evaluate_loss(observational, SplitTokens(args.data, args.split), limit=args.episodes)["total"]
    figures: dict[str, dict] = {}
    stands = args.stand_quantiles or [None]
    for rule, quantile in [(r, q) for r in args.rules for q in stands]:
        set_rule(model, rule)
        if quantile is not None:
            model.fit_stand_distance(encoder, train_texts, quantile)
            rule = f"{rule} stand {quantile:g}"
        rule_began = time.perf_counter()
        row = {s: evaluate_loss(model, d, limit=args.episodes)["total"] for s, d in sources.items()}
        row["loss_seconds"] = round(time.perf_counter() - rule_began, 1)  # what the rule costs to evaluate
        styles = [row[s] for s in sources if s != "dataset"]
        row["styles_mean"], row["styles_worst"] = float(np.mean(styles)), float(np.max(styles))
        if args.imagination_episodes:
            im = imagination_metrics(model, sources["dataset"], args.imagination_episodes, args.seed)
            row["reward_precision"], row["termination_precision"] = im.reward_precision, im.termination_precision
        imagined = {}
        if args.imagination_episodes and args.imagine_styles:
            imagined = {
                s: imagination_metrics(model, d, args.imagination_episodes, args.seed)
                for s, d in sources.items()
                if s != "dataset"
            }
            row["styles_reward_precision"] = {s: m.reward_precision for s, m in imagined.items()}
            row["styles_reward_precision_mean"] = float(np.mean(list(row["styles_reward_precision"].values())))
        figures[rule] = row
        print(
            f"{rule:20s} dataset {row['dataset']:.4f}  {args.part} styles mean {row['styles_mean']:.4f} "
            f"(x{row['styles_mean'] / blind:.2f} Observational's), worst {row['styles_worst']:.4f}"
            + (
                f"  imagined reward / termination precision {row['reward_precision']:.2f} / "
                f"{row['termination_precision']:.2f}"
                if args.imagination_episodes
                else ""
            )
            + (f", {args.part} styles' reward precision {row['styles_reward_precision_mean']:.2f}" if imagined else ""),
            flush=True,
        )
    print(f"{'observational':20s} {blind:.4f} whatever the text")
    if args.out:
        record = {
            "command": " ".join(sys.argv),
            "settings": {k: str(v) for k, v in vars(args).items()},
            "observational": blind,
            "rules": figures,
            "seconds": round(time.perf_counter() - began, 1),
        }
        args.out.write_text(json.dumps(record, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

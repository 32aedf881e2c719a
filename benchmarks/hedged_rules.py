"""How a hedged EMMA-LWM's reading rules compare (issue 30), on data they may be chosen on: the dev
part of the stress set and a dev split, never the held-out part or a test split.

For each rule, the teacher-forced cross-entropy (`evaluate_loss`, as `lwm eval`) with the
dataset's descriptions and with each style of the stress set's dev part (manuals re-drawn for the
same triples), and Table 2's imagined reward / termination precision (raw sampling) with the
dataset's text. Rules: "mean" (a description the words do not agree with is read as the mean
prototype of what they allow) and "mixture:W" (every reading the words allow, the model's own with
prior W and the model's entity, where the words name another, with prior Q;
`hedged_reading.readings`). Observational, which reads no text, is the line to beat.
Every figure comes from this one run, so the rules are compared on the same episodes and code.

    flock /tmp/lwm-heavy.lock .venv/bin/python benchmarks/hedged_rules.py --data data/human \\
        --rules mean mixture:0.8:0 mixture:0.8:0.15 --episodes 100 --imagination-episodes 200
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
from lwm_models.world.train import evaluate_loss  # noqa: E402
from lwm_models.world.training_data import SplitTokens, redraw_manuals  # noqa: E402

CHECKPOINTS = ROOT / "lwm_models" / "checkpoints"


def set_rule(model, rule: str) -> None:
    """Read with `rule`: "mean", or "mixture:W:Q" (W the prior of the model's own reading, default
    0.8; Q that of its entity where the words name another, default 0.15)."""
    name, *numbers = rule.split(":")
    if name == "mean" and not numbers:
        model.mixture = False
        return
    if name != "mixture" or len(numbers) > 2:
        raise LwmError(f"unknown rule {rule!r}: give mean or mixture:W[:Q] (priors, 0-1)")
    try:
        weights = [float(x) for x in numbers]
    except ValueError:
        raise LwmError(f"mixture:W:Q needs numbers, got {rule!r}") from None
    own, other = (weights + [0.8, 0.15][len(weights) :])[:2]
    if not (0.0 < own <= 1.0 and 0.0 <= other < 1.0):
        raise LwmError(f"the priors must be in (0, 1] and [0, 1), got {own} and {other}")
    model.mixture, model.own_weight, model.other_identity = True, own, other


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, required=True, help="dataset directory (lwm data generate)")
    parser.add_argument("--checkpoint", type=Path, default=CHECKPOINTS / "emma-lwm-hedged", help="a hedged EMMA-LWM")
    parser.add_argument("--split", default="newall-dev", help="a dev split")
    parser.add_argument("--rules", nargs="+", default=["mean", "mixture:0.8:0", "mixture:0.8:0.15"])
    parser.add_argument("--episodes", type=int, default=100, help="episodes of the cross-entropy (evenly spaced)")
    parser.add_argument("--imagination-episodes", type=int, default=200, help="0: no imagination")
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
        model, _ = load_checkpoint(args.checkpoint, kind="emma-hedged")
        for rule in args.rules:
            set_rule(model, rule)
        observational, _ = load_checkpoint(CHECKPOINTS / "observational")
        encoder = model.frozen_text_encoder()
        sources = {"dataset": SplitTokens(args.data, args.split, encoder, model.route)}
        for style in stress_styles():
            data = SplitTokens(args.data, args.split, None, model.route)
            redraw_manuals(data, stress_pools(style, "dev"), encoder, args.seed)
            sources[f"dev:{style}"] = data
    except (LwmError, OSError) as exc:
        print(f"hedged_rules: {exc}", file=sys.stderr)
        return 2
    blind = evaluate_loss(observational, SplitTokens(args.data, args.split), limit=args.episodes)["total"]
    figures: dict[str, dict] = {}
    for rule in args.rules:
        set_rule(model, rule)
        row = {s: evaluate_loss(model, d, limit=args.episodes)["total"] for s, d in sources.items()}
        if args.imagination_episodes:
            im = imagination_metrics(model, sources["dataset"], args.imagination_episodes, args.seed)
            row["reward_precision"], row["termination_precision"] = im.reward_precision, im.termination_precision
        styles = [v for s, v in row.items() if s.startswith("dev:")]
        row["styles_mean"], row["styles_worst"] = float(np.mean(styles)), float(np.max(styles))
        figures[rule] = row
        print(
            f"{rule:14s} dataset {row['dataset']:.4f}  dev styles mean {row['styles_mean']:.4f} "
            f"(x{row['styles_mean'] / blind:.2f} Observational's), worst {row['styles_worst']:.4f}"
            + (
                f"  imagined reward / termination precision {row['reward_precision']:.2f} / "
                f"{row['termination_precision']:.2f}"
                if args.imagination_episodes
                else ""
            ),
            flush=True,
        )
    print(f"{'observational':14s} {blind:.4f} whatever the text")
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

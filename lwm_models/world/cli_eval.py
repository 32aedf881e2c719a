"""`lwm eval`: Table 1 (cross-entropy) and Table 2 (imagination) for a checkpoint."""

from __future__ import annotations

import argparse
import json
import time

from .batches import SplitTokens, redraw_manuals
from .checkpoint import load_checkpoint
from .evaluate import evaluate_model, loss_by_prefix
from .frozen_text import FrozenTextEncoder
from .registry import NEEDS_TEXT


def load_router(kind: str):
    if kind != "gpthard":
        return None
    from ..text.parser import route_identity_id

    return route_identity_id


def run_eval(args: argparse.Namespace) -> int:
    model, config = load_checkpoint(args.checkpoint)
    kind = config["kind"]
    encoder = FrozenTextEncoder() if NEEDS_TEXT[kind] else None
    pools = None
    if args.texts:
        from ..text import DescriptionPools

        pools = DescriptionPools.from_files(args.texts, seed=args.seed)
    splits = {}
    for name in args.splits:
        data = SplitTokens(args.data, name, None if pools else encoder, load_router(kind))
        if pools is not None:
            redraw_manuals(data, pools, encoder, args.seed)
        splits[name] = data
    began = time.perf_counter()
    results = evaluate_model(model, splits, args.loss_episodes, args.imagination_episodes, args.seed)
    record = {
        "checkpoint": str(args.checkpoint),
        "kind": kind,
        "steps": config.get("steps"),
        "texts": args.texts or "dataset",
        "seed": args.seed,
        "results": results,
        "seconds": round(time.perf_counter() - began, 1),
    }
    print(f"{kind} ({config.get('steps')} steps) — cross-entropy, lower is better")
    print(f"{'split':<15} {'obs':>7} {'reward':>7} {'done':>7} {'total':>7}   dDist  r-prec  t-prec")
    for name, r in results.items():
        ce = r["cross_entropy"]
        im = r.get("imagination")
        tail = (
            f"   {im['delta_dist']:.2f}   {im['reward_precision']:.2f}    {im['termination_precision']:.2f}"
            if im
            else ""
        )
        print(f"{name:<15} {ce['obs']:7.4f} {ce['reward']:7.4f} {ce['done']:7.4f} {ce['total']:7.4f}{tail}")
    if args.plot:
        curves = {name: loss_by_prefix(model, data, limit=args.loss_episodes) for name, data in splits.items()}
        record["loss_by_prefix"] = curves
        plot_loss_by_prefix(curves, args.plot, title=f"{kind}: loss by history length")
        print(f"plot written to {args.plot}")
    if args.out:
        args.out.write_text(json.dumps(record, indent=2))
        print(f"results written to {args.out}")
    return 0


def plot_loss_by_prefix(curves: dict[str, dict], path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), dpi=120)
    for name, c in curves.items():
        ax.plot(c["step"], c["total"], label=name)
    ax.set_xlabel("step of the episode (blocks of history seen)")
    ax.set_ylabel("cross-entropy per token (obs + reward + done)")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)

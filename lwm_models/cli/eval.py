"""`lwm eval`: Table 1 (cross-entropy) and Table 2 (imagination) for a checkpoint."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from ..messenger.constants import SPLITS
from ..text.stress import PARTS
from .args import checkpoint_dir, existing_dir, nonnegative_int, positive_int

TEST_SPLITS = ["newcombo-test", "newattr-test", "newall-test"]


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("eval", help="evaluate a world model: cross-entropy and imagination metrics")
    p.add_argument("--checkpoint", type=checkpoint_dir, required=True, help="checkpoint directory")
    p.add_argument("--data", type=existing_dir, required=True, help="dataset directory")
    p.add_argument(
        "--splits", nargs="+", choices=SPLITS, default=TEST_SPLITS, metavar="SPLIT", help="splits to evaluate"
    )
    p.add_argument(
        "--loss-episodes", type=positive_int, default=None, help="episodes per split for cross-entropy (default: all)"
    )
    p.add_argument(
        "--imagination-episodes", type=nonnegative_int, default=200, help="episodes per split to imagine (0: skip)"
    )
    texts = p.add_mutually_exclusive_group()
    texts.add_argument(
        "--texts",
        nargs="+",
        default=None,
        metavar="PATH",
        help="re-draw the manuals from these description files (triples they lack: generated text, with a warning)",
    )
    texts.add_argument(
        "--stress",
        default=None,
        metavar="STYLE",
        help="re-draw the manuals from one style of the held-out stress set (lwm_models/text/stress_set.json)",
    )
    p.add_argument(
        "--stress-part",
        default="heldout",
        choices=PARTS,
        help="with --stress: the part to draw from (dev chooses between ways of reading; figures to report: heldout)",
    )
    p.add_argument(
        "--no-fill",
        action="store_true",
        help="with --texts: refuse, instead of filling with generated text, when the files lack a triple in use",
    )
    p.add_argument(
        "--constrained",
        action="store_true",
        help="also imagine under the game's rules (decoding constraints) and report those figures beside the raw ones",
    )
    p.add_argument("--seed", type=nonnegative_int, default=0, help="seed of the imagination and of re-drawn manuals")
    p.add_argument("--out", type=Path, default=None, help="write the results as JSON here")
    p.add_argument("--plot", type=Path, default=None, help="write loss against history length as PNG here")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..world.checkpoint import load_checkpoint
    from ..world.evaluate import evaluate_model, loss_by_prefix
    from ..world.training_data import SplitTokens, redraw_manuals

    model, config = load_checkpoint(args.checkpoint)
    kind = config["kind"]
    encoder = model.frozen_text_encoder()
    pools = None
    if args.texts:
        from ..text import DescriptionPools

        pools = DescriptionPools.from_files(args.texts, seed=args.seed)
    elif args.stress:
        from ..text.stress import stress_pools

        pools = stress_pools(args.stress, args.stress_part)
    splits = {}
    filled: dict[str, dict[str, int]] = {}
    for name in args.splits:
        data = SplitTokens(args.data, name, None if pools else encoder, model.route)
        if pools is not None:
            redraw_manuals(data, pools, encoder, args.seed)
            filled[name] = filled_slots(data, pools, args.loss_episodes)
        splits[name] = data
    for name, f in filled.items():
        if f["filled"]:
            # The files lack these triples, so part of every figure below is about generated text.
            share = f["filled"] / f["slots"]
            line = (
                f"{name}: {f['filled']} of {f['slots']} manual slots ({share:.1%}) use generated descriptions: "
                "the description files have none of their triples"
            )
            if args.no_fill:
                print(f"lwm eval: refused (--no-fill): {line}", file=sys.stderr)
                return 2
            print(f"warning: {line}", file=sys.stderr)
    began = time.perf_counter()
    results = evaluate_model(
        model, splits, args.loss_episodes, args.imagination_episodes, args.seed, constrained=args.constrained
    )
    record = {
        "checkpoint": str(args.checkpoint),
        "kind": kind,
        "steps": config.get("steps"),
        "texts": args.texts or (f"stress:{args.stress_part}:{args.stress}" if args.stress else "dataset"),
        "filled_slots": filled,
        "seed": args.seed,
        "results": results,
        "seconds": round(time.perf_counter() - began, 1),
    }
    print(f"{kind} ({config.get('steps')} steps) — cross-entropy, lower is better")
    print(f"{'split':<15} {'obs':>7} {'reward':>7} {'done':>7} {'total':>7}")
    for name, r in results.items():
        ce = r["cross_entropy"]
        print(f"{name:<15} {ce['obs']:7.4f} {ce['reward']:7.4f} {ce['done']:7.4f} {ce['total']:7.4f}")
    imagined = {name: r["imagination"] for name, r in results.items() if r.get("imagination")}
    for name, r in results.items():
        if "imagination_constrained" in r:
            imagined[f"{name} (rules)"] = r["imagination_constrained"]
    if imagined:
        # Precision and recall of imagined rewards and terminations against the real episodes; the
        # consistency rates are 0 in real episodes (identity changes and vanishings per transition
        # and entity channel, jumps per avatar move, rewards with nothing within one cell).
        print(
            f"{'imagination':<22} {'dDist':>6} {'r-prec':>6} {'r-rec':>6} {'t-prec':>6} {'t-rec':>6} "
            f"{'id-chg':>7} {'jump':>7} {'vanish':>7} {'r-far':>6} {'breaks':>6}"
        )
        for name, im in imagined.items():
            print(
                f"{name:<22} {im['delta_dist']:6.2f} {im['reward_precision']:6.2f} {im['reward_recall']:6.2f} "
                f"{im['termination_precision']:6.2f} {im['termination_recall']:6.2f} "
                f"{im['identity_change_rate']:7.2%} {im['avatar_jump_rate']:7.2%} {im['vanish_rate']:7.2%} "
                f"{im['reward_without_reach']:6.2f} {im['rule_breaks_per_step']:6.3f}"
            )
    leaks = {name: r["impossible_mass"] for name, r in results.items() if "impossible_mass" in r}
    if leaks:
        # Teacher-forced on real episodes: probability per step on tokens the game's rules forbid.
        print(f"{'impossible mass':<22} {'step':>7} {'ids':>7} {'cells':>7} {'reward':>7} {'done':>7}")
        for name, m in leaks.items():
            print(
                f"{name:<22} {m['per_step']:7.4f} {m['identity']:7.4f} {m['position']:7.4f} "
                f"{m['reward']:7.4f} {m['done']:7.4f}"
            )
    if args.plot:
        curves = {name: loss_by_prefix(model, data, limit=args.loss_episodes) for name, data in splits.items()}
        record["loss_by_prefix"] = curves
        plot_loss_by_prefix(curves, args.plot, title=f"{kind}: loss by history length")
        print(f"plot written to {args.plot}")
    if args.out:
        args.out.write_text(json.dumps(record, indent=2))
        print(f"results written to {args.out}")
    return 0


def filled_slots(data, pools, limit: int | None = None) -> dict[str, int]:
    """How many manual slots of the episodes the cross-entropy reads (`limit` of them) drew from a
    pool that `pools` filled with generated text."""
    from ..messenger.constants import ALL_TRIPLES

    fallbacks = set(getattr(pools, "fallbacks", ()))
    parses = [data.ds.parses[int(e)] for e in data.evaluated_episodes(limit)]
    slots = [(data.split, ALL_TRIPLES[int(i)]) for parse in parses for i in parse]
    return {"slots": len(slots), "filled": sum(s in fallbacks for s in slots)}


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

#!/usr/bin/env python
"""Make a hedged checkpoint (lwm_models/world/hedged_reading.py) from an EMMA-LWM or a GPTHard one:
the same weights, plus the 108 triple prototypes fitted from the project's generated
descriptions and the distance within which a reading stands (from the dataset's training
descriptions; none for GPTHard, world/hedged_gpthard.py). Nothing is trained; it takes seconds.

    .venv/bin/python scripts/hedged_checkpoint.py --data data/human \\
        --source lwm_models/checkpoints/emma-lwm-reader --out lwm_models/checkpoints/emma-lwm-hedged \\
        --stand-quantile 0 --ground --max-readings 125 --keep-readings 9
    .venv/bin/python scripts/hedged_checkpoint.py --data data/human \\
        --source lwm_models/checkpoints/gpthard --out lwm_models/checkpoints/gpthard-hedged --ground \\
        --max-readings 125 --keep-readings 9
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.errors import LwmError  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint, read_config, save_checkpoint  # noqa: E402
from lwm_models.world.hedged_gpthard import HedgedGPTHardLWM  # noqa: E402
from lwm_models.world.hedged_reading import (  # noqa: E402
    DOUBT,
    MAX_READINGS,
    PROTOTYPE_TEXTS,
    PRUNE_STEPS,
    STAND_QUANTILE,
    HedgedEmmaLWM,
)
from lwm_models.world.reader_tuning import dataset_descriptions  # noqa: E402
from lwm_models.world.training_data import SplitTokens  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", type=Path, required=True, help="an EMMA-LWM or GPTHard checkpoint directory")
    ap.add_argument("--out", type=Path, required=True, help="the hedged checkpoint's directory (replaced)")
    ap.add_argument(
        "--data", type=Path, required=True, help="dataset whose training split's descriptions set the stand distance"
    )
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated descriptions drawn per triple")
    ap.add_argument(
        "--stand-quantile",
        type=float,
        default=None,
        help=f"quantile of the training descriptions' distances within which a reading stands "
        f"(default {STAND_QUANTILE} for EMMA-LWM, 0 for GPTHard: none stands)",
    )
    ap.add_argument(
        "--ground",
        action="store_true",
        help="ground the words' entities on the board before reading (hedged_reading.ground_words)",
    )
    ap.add_argument(
        "--doubt",
        type=float,
        default=DOUBT,
        help=f"prior of the triples one decided field away from the words (hedged_reading.readings; default {DOUBT})",
    )
    ap.add_argument(
        "--max-readings",
        type=int,
        default=MAX_READINGS,
        help=f"readings of a manual kept where an episode weighs them (default {MAX_READINGS})",
    )
    ap.add_argument(
        "--keep-readings",
        type=int,
        default=0,
        help=f"of them, those that predict after an episode's first {PRUNE_STEPS} steps, the likeliest then "
        "(default 0: all)",
    )
    args = ap.parse_args()
    if args.max_readings < 1 or args.keep_readings < 0:
        print("hedged_checkpoint: --max-readings must be 1 or more and --keep-readings 0 or more", file=sys.stderr)
        return 2
    hedged_kinds = {"emma": (HedgedEmmaLWM, STAND_QUANTILE), "gpthard": (HedgedGPTHardLWM, 0.0)}
    try:
        model, config = load_checkpoint(args.source)
        if config["kind"] not in hedged_kinds:
            raise LwmError(f"{args.source} holds a {config['kind']!r} model; give an EMMA-LWM or a GPTHard one")
        texts, _ = dataset_descriptions(SplitTokens(args.data, "train", None, None))
        meta = {k: v for k, v in read_config(args.source).items()
                if k not in ("format", "version", "kind", "config", "dtype", "parameters", "sha256")}  # fmt: skip
    except LwmError as exc:
        print(f"hedged_checkpoint: {exc}", file=sys.stderr)
        return 2
    kind, default_quantile = hedged_kinds[config["kind"]]
    quantile = default_quantile if args.stand_quantile is None else args.stand_quantile
    hedged = kind(model.config)
    hedged.load_state_dict(model.state_dict(), strict=False)  # all but the prototypes
    hedged.eval()
    encoder = hedged.frozen_text_encoder()
    hedged.fit_prototypes(encoder, seed=args.seed)
    hedged.fit_stand_distance(encoder, texts, quantile)
    meta["hedged_reading"] = {
        "source": str(args.source),
        "data": str(args.data),
        "seed": args.seed,
        "prototype_texts": PROTOTYPE_TEXTS,
        "stand_quantile": quantile,
        "stand_distance": round(float(hedged.stand_distance), 4),
        "rule": "mixture",  # read every way the words allow (hedged_reading.readings)
        "ground": args.ground,
        "doubt": args.doubt,
        "max_readings": args.max_readings,
        "keep_readings": args.keep_readings,
    }
    save_checkpoint(hedged, args.out, meta, dtype=torch.float16)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

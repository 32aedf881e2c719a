#!/usr/bin/env python
"""Make a hedged EMMA-LWM checkpoint (lwm_models/world/hedged_reading.py) from an EMMA-LWM one:
the same weights, plus the 108 triple prototypes fitted from the project's generated
descriptions. Nothing is trained; it takes seconds.

    .venv/bin/python scripts/hedged_checkpoint.py \\
        --source lwm_models/checkpoints/emma-lwm-reader --out lwm_models/checkpoints/emma-lwm-hedged
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
from lwm_models.world.hedged_reading import PROTOTYPE_TEXTS, HedgedEmmaLWM  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--source", type=Path, required=True, help="an EMMA-LWM checkpoint directory")
    ap.add_argument("--out", type=Path, required=True, help="the hedged checkpoint's directory (replaced)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the generated descriptions drawn per triple")
    args = ap.parse_args()
    try:
        model, _ = load_checkpoint(args.source, kind="emma")
        meta = {k: v for k, v in read_config(args.source).items()
                if k not in ("format", "version", "kind", "config", "dtype", "parameters", "sha256")}  # fmt: skip
    except LwmError as exc:
        print(f"hedged_checkpoint: {exc}", file=sys.stderr)
        return 2
    hedged = HedgedEmmaLWM(model.config)
    hedged.load_state_dict(model.state_dict(), strict=False)  # all but the prototypes
    hedged.eval()
    hedged.fit_prototypes(hedged.frozen_text_encoder(), seed=args.seed)
    meta["hedged_reading"] = {"source": str(args.source), "prototype_texts": PROTOTYPE_TEXTS, "seed": args.seed}
    save_checkpoint(hedged, args.out, meta, dtype=torch.float16)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

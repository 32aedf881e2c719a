"""`lwm export`: copy a checkpoint for shipping, optionally as float16."""

from __future__ import annotations

import argparse
from pathlib import Path

from .args import checkpoint_dir


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="copy a checkpoint for shipping (optionally fp16)")
    p.add_argument("--checkpoint", type=checkpoint_dir, required=True, help="checkpoint directory to copy")
    p.add_argument("--out", type=Path, required=True, help="directory to write the copy to")
    p.add_argument("--fp16", action="store_true", help="store the weights as float16")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from ..world.checkpoint import load_checkpoint, save_checkpoint

    model, config = load_checkpoint(args.checkpoint)
    keep = {
        k: v
        for k, v in config.items()
        if k not in ("format", "version", "kind", "config", "dtype", "sha256", "parameters")
    }
    keep["exported_from"] = str(args.checkpoint)
    save_checkpoint(model, args.out, keep, dtype=torch.float16 if args.fp16 else None)
    size = (args.out / "model.safetensors").stat().st_size
    print(f"exported {config['kind']} to {args.out} ({size / 1e6:.1f} MB)")
    return 0

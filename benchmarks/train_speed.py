"""Training speed, in one run: seconds per optimizer step of a world model on real batches (32
segments of the training split) for each variant of a set, and the ratio to the set's first:
`parts` (default) the batch computed in parts of similar-length segments, `cpu-options` the
allocator, bf16, attention dropout, multi-query attention and threads.

    .venv/bin/python benchmarks/train_speed.py --data data/human [--set parts|cpu-options] [--preset small]
        [--kind emma] [--steps 12]

Every variant runs in its own process, because the allocator setting (GLIBC_TUNABLES) only takes
effect when set before Python starts. Machines here are noisy: compare the ratios of one run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

from lwm_models.cli.main import ALLOCATOR_TUNABLES

VARIANTS = {
    # name: (allocator tunables, bf16, attention dropout (None: preset's), threads, kv_heads (None:
    # preset's), parts: the batch computed as this many groups of similar-length segments)
    "cpu-options": [
        ("fp32, glibc default malloc", False, False, 0.1, 2, None, 1),
        ("fp32, allocator tunables", True, False, 0.1, 2, None, 1),
        ("+ bf16 autocast", True, True, 0.1, 2, None, 1),
        ("+ attention dropout 0", True, True, 0.0, 2, None, 1),
        ("+ multi-query attention", True, True, 0.0, 2, 1, 1),
        ("bf16 MQA, 1 thread", True, True, 0.0, 1, 1, 1),
    ],
    # The long runs' setting (fp32, 1 thread, the small preset's attention) with the batch in parts.
    "parts": [
        ("fp32, 1 thread, one padded batch", True, False, None, 1, None, 1),
        ("fp32, 1 thread, 2 parts", True, False, None, 1, None, 2),
        ("fp32, 1 thread, 4 parts (default)", True, False, None, 1, None, 4),
        ("fp32, 1 thread, 8 parts", True, False, None, 1, None, 8),
    ],
}

CHILD = r"""
import json, sys, time
from dataclasses import replace
import numpy as np, torch
from lwm_models.world.training_data import SplitTokens
from lwm_models.world.base import WorldModelConfig
from lwm_models.world.registry import PRESETS, build_model
from lwm_models.world.train import _param_groups, batch_loss
a = json.loads(sys.argv[1])
torch.set_num_threads(a["threads"])
base = PRESETS[a["preset"]]
over = {k: a[k] for k in ("attn_dropout", "kv_heads") if a[k] is not None}
cfg = WorldModelConfig(replace(base.decoder, **over), base.text)
torch.manual_seed(0)
model = build_model(a["kind"], cfg).train()
data = SplitTokens(a["data"], "train", model.frozen_text_encoder(), model.route)
opt = torch.optim.AdamW(_param_groups(model, 0.01), lr=1e-4)
rng = np.random.default_rng(0)
def step():
    parts = data.sample_parts(rng, 32, a["parts"])
    with torch.autocast("cpu", dtype=torch.bfloat16, enabled=a["bf16"]):
        out = batch_loss([model(*p) for p in parts])
    opt.zero_grad(); out.loss.backward(); torch.nn.utils.clip_grad_norm_(model.parameters(), 10); opt.step()
for _ in range(3):
    step()
t = time.perf_counter()
for _ in range(a["steps"]):
    step()
print(json.dumps({"s_per_step": (time.perf_counter() - t) / a["steps"]}))
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--preset", default="small")
    parser.add_argument("--kind", default="emma")
    parser.add_argument("--steps", type=int, default=12, help="timed steps per variant (after 3 warm-up steps)")
    parser.add_argument("--set", choices=list(VARIANTS), default="parts", help="which variants to compare")
    args = parser.parse_args()
    print(f"{args.kind} / {args.preset}, batch 32, {args.steps} timed steps per variant")
    baseline = None
    for name, tunables, bf16, attn_dropout, threads, kv_heads, parts in VARIANTS[args.set]:
        env = {k: v for k, v in os.environ.items() if k != "GLIBC_TUNABLES"}
        if tunables:
            env["GLIBC_TUNABLES"] = ALLOCATOR_TUNABLES
        spec = {
            "data": args.data,
            "preset": args.preset,
            "kind": args.kind,
            "steps": args.steps,
            "bf16": bf16,
            "attn_dropout": attn_dropout,
            "threads": threads,
            "kv_heads": kv_heads,
            "parts": parts,
        }
        proc = subprocess.run(
            [sys.executable, "-c", CHILD, json.dumps(spec)], capture_output=True, text=True, env=env, timeout=1800
        )
        if proc.returncode != 0:
            print(f"{name:<36} failed: {proc.stderr.strip().splitlines()[-1]}")
            continue
        s = json.loads(proc.stdout.strip().splitlines()[-1])["s_per_step"]
        baseline = baseline or s
        print(f"{name:<36} {s:6.3f} s/step  {3600 / s:7.0f} steps/h  {baseline / s:4.2f}x")


if __name__ == "__main__":
    main()

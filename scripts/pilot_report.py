#!/usr/bin/env python
"""Summarise world-model runs side by side: the pilot (scripts/pilot.sh, runs/pilot-*) by default,
or the long runs (`--pattern 'long-*'`, scripts/long_run.sh): per run, the steps done, the speed,
and the NewAll-dev cross-entropy at equal CPU time and at equal steps; plots dev CE against CPU
time and against steps.

Reads runs/pilot-*/metrics.jsonl (partial runs are fine). Times are the run's CPU seconds over
all its chunks (data loading excluded, evaluations included), as `--cpu-budget-minutes` counts
them; runs logged before CPU time was recorded fall back to wall-clock. CE "at T minutes" is that
of the last dev evaluation that had begun by T.

Usage: .venv/bin/python scripts/pilot_report.py [--runs runs] [--png results/pilot/dev-ce.png]
       [--minutes 10 20 30 40] [--steps 250 500 750 1000 1250]
       [--pattern 'long-*'] [--extra NAME=METRICS.jsonl ...] [--title TEXT]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
from pathlib import Path

ORDER = ["base", "mha", "attndrop", "lr1e-3", "seed1", "bf16"]


def load(path: Path) -> tuple[list[dict], list[dict]]:
    """(train lines, dev lines) of a metrics.jsonl; a torn last line is ignored."""
    train, dev = [], []
    for line in path.read_text().splitlines():
        try:
            entry = json.loads(line)
        except json.JSONDecodeError:
            continue
        (dev if "dev_total" in entry else train).append(entry)
    # Dev lines of older runs carry no time: take that of the train line at the same step.
    when = {e["step"]: e.get("cpu_s", e.get("elapsed_s")) for e in train}
    for e in train:
        e["t"] = e.get("cpu_s", e.get("elapsed_s", math.nan))
    for e in dev:
        e["t"] = e.get("cpu_s", e.get("elapsed_s", when.get(e["step"], math.nan)))
    # The final evaluation can be recorded twice (time budget and last step): keep the first.
    seen, unique = set(), []
    for e in dev:
        if e["step"] not in seen:
            seen.add(e["step"])
            unique.append(e)
    return train, unique


def speed(train: list[dict], dev_steps: set[int]) -> tuple[float, float]:
    """Median wall-clock and CPU seconds per step over 50-step windows without an evaluation."""
    wall, cpu = [], []
    for a, b in zip(train, train[1:]):
        if a["step"] in dev_steps or b["step"] <= a["step"]:
            continue
        n = b["step"] - a["step"]
        wall.append((b["elapsed_s"] - a["elapsed_s"]) / n)
        if "cpu_s" in a and "cpu_s" in b:
            cpu.append((b["cpu_s"] - a["cpu_s"]) / n)
    return (statistics.median(wall) if wall else math.nan, statistics.median(cpu) if cpu else math.nan)


def at_minutes(dev: list[dict], minutes: float) -> dict | None:
    began = [e for e in dev if e["t"] <= 60 * minutes]
    return began[-1] if began else None


def status(run: Path) -> str:
    """done, paused (a chunk ended with budget and steps left) or running?, from the run's own
    files: the saved state's step and CPU clock against the step count and CPU budget of its
    command (cmd.txt, written by scripts/long_run.sh)."""
    if run.is_file():
        return "(file)"
    if (run / "DONE").is_file():
        return "done"
    if not (run / "metrics.jsonl").is_file():
        return "not started"
    state, cmd = run / "last" / "train_state.json", run / "cmd.txt"
    if not (state.is_file() and cmd.is_file()):
        return "running?"
    saved = json.loads(state.read_text())
    args = cmd.read_text().split()

    def arg(flag: str) -> float | None:
        return float(args[args.index(flag) + 1]) if flag in args[:-1] else None

    steps, budget = arg("--steps"), arg("--cpu-budget-minutes")
    if (steps is not None and saved["step"] >= steps) or (
        budget is not None and saved.get("clock", {}).get("cpu_s", 0.0) >= 60 * budget
    ):
        return "done"
    last_logged = max((e.get("step", 0) for e in load(run / "metrics.jsonl")[0]), default=0)
    return "paused" if saved["step"] >= last_logged else "training?"


def fmt(x: float | None, digits: int = 4) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", default="runs", help="directory holding pilot-<variant>/")
    ap.add_argument("--png", default="results/pilot/dev-ce.png", help="plot file ('' for none)")
    ap.add_argument("--minutes", type=float, nargs="+", default=[10, 20, 30, 40])
    ap.add_argument("--steps", type=int, nargs="+", default=[250, 500, 750, 1000, 1250])
    ap.add_argument("--pattern", default="pilot-*", help="run directories under --runs (the name follows the '-')")
    ap.add_argument("--extra", nargs="*", default=[], metavar="NAME=FILE", help="more runs, by their metrics.jsonl")
    ap.add_argument("--title", default="EMMA-LWM pilot (small preset, cosine schedule of the long run, 1 thread)")
    args = ap.parse_args()

    def name_of(p: Path) -> str:
        return p.name.split("-", 1)[1]

    runs = sorted(
        (p for p in Path(args.runs).glob(args.pattern) if p.is_dir() and ".partial-" not in p.name),
        key=lambda p: (ORDER.index(name_of(p)) if name_of(p) in ORDER else len(ORDER), p.name),
    )
    data = {}
    for run in runs:
        metrics = run / "metrics.jsonl"
        if metrics.is_file():
            data[name_of(run)] = (run, *load(metrics))
    for pair in args.extra:
        name, _, path = pair.partition("=")
        if not Path(path).is_file():
            print(f"no metrics file {path}")
            return 1
        data[name] = (Path(path), *load(Path(path)))
    if not data:
        print(f"no runs with metrics under {args.runs}/{args.pattern}")
        return 1

    mins = " ".join(f"{'@' + format(m, 'g') + 'min':>16}" for m in args.minutes)
    print(f"{'variant':<10} {'status':<11} {'steps':>6} {'min':>6} {'s/step':>7} {'cpu/step':>8} {'eval_s':>6}  {mins}")
    for name, (run, train, dev) in data.items():
        steps = max([e["step"] for e in train + dev], default=0)
        minutes = max([e["t"] for e in train] + [0]) / 60
        wall, cpu = speed(train, {e["step"] for e in dev})
        evals = [e["eval_s"] for e in dev if "eval_s" in e]
        cells = []
        for m in args.minutes:
            e = at_minutes(dev, m) if 60 * m <= 60 * minutes + 1 or status(run) == "done" else None
            cells.append(f"{fmt(e['dev_total']) + ' (' + str(e['step']) + ')' if e else '-':>16}")
        mean_eval = statistics.mean(evals) if evals else None
        print(
            f"{name:<10} {status(run):<11} {steps:>6} {minutes:>6.1f} {fmt(wall, 3):>7} {fmt(cpu, 3):>8} "
            f"{fmt(mean_eval, 1):>6}  {' '.join(cells)}"
        )
    print("  @T min: NewAll-dev total CE (step) of the last evaluation begun by T CPU minutes of training")
    print("  ('-' while a run has not trained that long yet)")

    print(f"\n{'variant':<10} " + " ".join(f"{'step ' + str(s):>11}" for s in args.steps) + f" {'best':>16}")
    for name, (_, _, dev) in data.items():
        by_step = {e["step"]: e["dev_total"] for e in dev}
        best = min(dev, key=lambda e: e["dev_total"]) if dev else None
        row = " ".join(f"{fmt(by_step.get(s)):>11}" for s in args.steps)
        print(f"{name:<10} {row} {fmt(best['dev_total']) + ' (' + str(best['step']) + ')' if best else '-':>16}")
    print("  NewAll-dev total CE at equal steps (the per-step quality, whatever the speed)")

    if args.png:
        try:
            import matplotlib

            matplotlib.use("Agg")
            import matplotlib.pyplot as plt
        except ImportError:
            print("\nmatplotlib is not installed: no plot")
            return 0
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5), sharey=True)
        for name, (_, _, dev) in data.items():
            if not dev:
                continue
            axes[0].plot([e["t"] / 60 for e in dev], [e["dev_total"] for e in dev], marker=".", label=name)
            axes[1].plot([e["step"] for e in dev], [e["dev_total"] for e in dev], marker=".", label=name)
        axes[0].set_xlabel("training CPU time (min, 1 thread, evaluations included)")
        axes[1].set_xlabel("step")
        axes[0].set_ylabel("NewAll-dev total CE")
        for ax in axes:
            ax.set_yscale("log")
            ax.grid(True, which="both", alpha=0.3)
            ax.legend()
        fig.suptitle(args.title)
        fig.tight_layout()
        Path(args.png).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(args.png, dpi=110)
        print(f"\nplot: {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

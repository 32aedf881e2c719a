#!/usr/bin/env python
"""Write the result tables of README.md and docs/*.md from the files in results/.

A table lives in a Markdown file between `<!-- table:NAME -->` and `<!-- /table:NAME -->`; this
script replaces what stands between the two markers with the table made from results/, so that
no figure is copied by hand. `tests/test_results_tables.py` fails when a committed table differs
from what the script makes.

    .venv/bin/python scripts/results_tables.py           # rewrite every marked table
    .venv/bin/python scripts/results_tables.py --check   # exit 1 naming the tables that are stale
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
DOCS = ("README.md", "docs/*.md")
SPLITS = ("newcombo-test", "newattr-test", "newall-test")

# The paper's published figures (test splits NewCombo, NewAttr, NewAll), to compare with.
PAPER_CE = {
    "observational": (0.12, 0.18, 0.19),
    "standard": (0.10, 0.15, 0.16),
    "gpthard": (0.10, 0.15, 0.16),
    "emma": (0.08, 0.10, 0.13),
    "oracle": (0.08, 0.09, 0.12),
}
PAPER_IMAGINATION = {  # delta_dist, reward precision, termination precision
    "observational": ((2.04, 2.91, 3.00), (0.39, 0.20, 0.15), (0.51, 0.33, 0.28)),
    "emma": ((0.57, 1.14, 1.29), (0.88, 0.69, 0.70), (0.88, 0.75, 0.71)),
    "oracle": ((0.49, 0.77, 0.92), (0.93, 0.81, 0.77), (0.89, 0.84, 0.79)),
}
# the shipped world models, in the paper's order (lwm_models/world/shipped.py): (name in Table 3's
# records, kind (the paper's figures), name, evaluation file)
sys.path.insert(0, str(ROOT))
from lwm_models.world.shipped import WORLD_MODELS  # noqa: E402

# The paper's figures by the kind they belong to: a hedged model is the same model read differently.
PAPER_KIND = {"emma-hedged": "emma", "gpthard-hedged": "gpthard"}
SHIPPED = tuple((m.key, PAPER_KIND.get(m.kind, m.kind), m.title, f"table1-2/{m.directory}.json") for m in WORLD_MODELS)
TABLE3_MODELS = (("observational", "Observational"), ("emma", "EMMA-LWM"), ("oracle", "OracleParse"))
TABLE3_SETTINGS = (  # (setting, label, what it learns from: which rows rest on the hand-written controller)
    ("online_il", "Online IL", "the rule-based expert's labels"),
    ("filtered_bc", "Filtered BC (near-optimal expert)", "the rule-based expert's imagined plans"),
    ("filtered_bc_suboptimal", "Filtered BC (suboptimal expert)", "a policy cloned from the rule-based expert"),
)
NO_CONTROLLER_RECORDS = "imagined-returns/records-30-games-newall.jsonl"
SERVED_NO_CONTROLLER_RECORDS = "imagined-returns/records-10-games-newall.jsonl"  # the served model, fewer games
SPLIT_HEAD = "| NewCombo | NewAttr | NewAll |"


def _load(name: str) -> dict:
    return json.loads((RESULTS / name).read_text())


def _load_jsonl(name: str) -> list[dict]:
    """The records of a JSONL file in results/, one per non-empty line."""
    return [json.loads(line) for line in (RESULTS / name).read_text().splitlines() if line.strip()]


def _paper_table3() -> dict:
    from lwm_models.cli.table3 import PAPER

    return PAPER


def _per_split(values, fmt: str, paper=None) -> str:
    cells = []
    for i, v in enumerate(values):
        cell = format(v, fmt)
        if paper is not None:
            cell += f" [{paper[i]:.2f}]"
        cells.append(cell)
    return " / ".join(cells)


def _link(name: str, base: str) -> str:
    return f"[{Path(name).name}]({base}results/{name})"


def _model_label(name: str, steps: int) -> str:
    return f"{name} (step {steps:,})"


# --------------------------------------------------------------------------- tables
def table1(base: str) -> list[str]:
    lines = ["| model | NewCombo | NewAttr | NewAll | file |", "|---|---|---|---|---|"]
    for _, kind, name, path in SHIPPED:
        d = _load(path)
        ce = [d["results"][s]["cross_entropy"]["total"] for s in SPLITS]
        cells = " | ".join(f"{v:.3f} [{p:.2f}]" for v, p in zip(ce, PAPER_CE[kind], strict=True))
        lines.append(f"| {_model_label(name, d['steps'])} | {cells} | {_link(path, base)} |")
    return lines


def table2(base: str) -> list[str]:
    lines = [
        "| model | Delta_dist Combo / Attr / All | reward precision | termination precision |",
        "|---|---|---|---|",
    ]
    for _, kind, name, path in SHIPPED:
        d = _load(path)
        im = [d["results"][s]["imagination"] for s in SPLITS]
        paper = PAPER_IMAGINATION.get(kind, (None, None, None))
        cells = [
            _per_split([m["delta_dist"] for m in im], ".2f", paper[0]),
            _per_split([m["reward_precision"] for m in im], ".2f", paper[1]),
            _per_split([m["termination_precision"] for m in im], ".2f", paper[2]),
        ]
        lines.append(f"| {_model_label(name, d['steps'])} | " + " | ".join(cells) + " |")
    return lines


def rules(base: str) -> list[str]:
    lines = [
        "| model | sampling | reward precision | reward recall | termination precision | termination recall |",
        "|---|---|---|---|---|---|",
    ]
    for _, _, name, path in SHIPPED:
        d = _load(path)
        for key, how in (("imagination", "raw"), ("imagination_constrained", "rules")):
            im = [d["results"][s][key] for s in SPLITS]
            cells = [
                _per_split([m[k] for m in im], ".2f")
                for k in ("reward_precision", "reward_recall", "termination_precision", "termination_recall")
            ]
            lines.append(f"| {_model_label(name, d['steps'])} | {how} | " + " | ".join(cells) + " |")
    return lines


def consistency(base: str) -> list[str]:
    lines = [
        "| model | reward with nothing in reach | identity changes | avatar jumps | vanishings "
        "| rule breaks per step |",
        "|---|---|---|---|---|---|",
    ]
    for _, _, name, path in SHIPPED:
        d = _load(path)
        im = [d["results"][s]["imagination"] for s in SPLITS]
        cells = [_per_split([m["reward_without_reach"] for m in im], ".2f")]
        for key in ("identity_change_rate", "avatar_jump_rate", "vanish_rate"):
            cells.append(" / ".join(f"{100 * m[key]:.2f}%" for m in im))
        cells.append(_per_split([m["rule_breaks_per_step"] for m in im], ".3f"))
        lines.append(f"| {_model_label(name, d['steps'])} | " + " | ".join(cells) + " |")
    return lines


def _return(row: dict, paper: float | None) -> str:
    low, high = row["ci95"]
    text = f"{row['mean']:+.2f} ({low:+.2f}, {high:+.2f})"
    return text if paper is None else f"{text} [{paper:.2f}]"


def table3(base: str) -> list[str]:
    from lwm_models.stats import mean_interval

    rows, paper = _load("table3/summary-30-games.json")["rows"], _paper_table3()
    lines = ["| setting | learns from | model " + SPLIT_HEAD, "|---|---|---|---|---|---|"]
    for setting, label, source in TABLE3_SETTINGS:
        for kind, name in TABLE3_MODELS:
            row = rows.get(f"{setting}/{kind}", {})
            cells = [
                _return(row[s], paper[(setting, kind)][i]) if s in row else "not measured" for i, s in enumerate(SPLITS)
            ]
            lines.append(f"| {label} | {source} | {name} | " + " | ".join(cells) + " |")
    learnt = _load_jsonl(NO_CONTROLLER_RECORDS) if (RESULTS / NO_CONTROLLER_RECORDS).is_file() else []
    for kind, name in TABLE3_MODELS:
        returns = [r["return"] for r in learnt if r["model"] == kind and r["split"] == "newall-test"]
        if returns:
            mean, low, high = mean_interval(returns)
            lines.append(
                f"| Imagined returns | the world model alone (no controller) | {name} | not measured | not measured "
                f"| {mean:+.2f} ({low:+.2f}, {high:+.2f}) |"
            )
    return lines


def summary(base: str) -> list[str]:
    """One line per shipped model: test cross-entropy and Table 3's online imitation on NewAll."""
    rows, paper3 = _load("table3/summary-30-games.json")["rows"], _paper_table3()
    lines = [
        "| model | test cross-entropy, NewCombo / NewAttr / NewAll [paper] "
        "| real return after online imitation, NewAll, 30 games [paper] |",
        "|---|---|---|",
    ]
    for key, kind, name, path in SHIPPED:
        d = _load(path)
        ce = [d["results"][s]["cross_entropy"]["total"] for s in SPLITS]
        row = rows.get(f"online_il/{key}")
        paper = paper3.get(("online_il", kind))  # the paper ran no GPTHard in Table 3
        ret = "not measured" if row is None else _return(row["newall-test"], None if paper is None else paper[2])
        lines.append(f"| {_model_label(name, d['steps'])} | {_per_split(ce, '.3f', PAPER_CE[kind])} | {ret} |")
    return lines


def review_loop(base: str) -> list[str]:
    from lwm_models.stats import mean_interval

    path = "review-loop/emma-lwm.jsonl"
    games = _load_jsonl(path)
    mean, low, high = mean_interval([g["real_return"] for g in games])
    outcomes = [g["outcome"] for g in games]
    counts = ", ".join(f"{outcomes.count(o)} {o}" for o in ("won", "died", "time_limit", "aborted") if o in outcomes)
    died = sum(g["approved_plan_died"] for g in games)
    return [
        "| games (NewAll test) | real return, mean (95% t interval) | outcomes "
        "| approved plans whose shown trajectory died | file |",
        "|---|---|---|---|---|",
        f"| {len(games)} | {mean:+.2f} ({low:+.2f}, {high:+.2f}) | {counts} | {died} | {_link(path, base)} |",
    ]


def review_loop_variants(base: str) -> list[str]:
    """The review loop with plans and learning rounds imagined raw or under the game's rules."""
    lines = [
        "| plans / learning rounds | real return, mean | won / died / time limit / aborted "
        "| approved plans whose shown trajectory died | file |",
        "|---|---|---|---|---|",
    ]
    for path, label in (
        ("review-loop/plans-raw.jsonl", "raw / raw (`--no-constrained`)"),
        ("review-loop/plans-rules.jsonl", "rules / raw (`--constrained`, the default)"),
        ("review-loop/plans-and-learning-rules.jsonl", "rules / rules (`--constrained --constrained-learning`)"),
    ):
        games = _load_jsonl(path)
        mean = sum(g["real_return"] for g in games) / len(games)
        outcomes = [g["outcome"] for g in games]
        counts = " / ".join(str(outcomes.count(o)) for o in ("won", "died", "time_limit", "aborted"))
        died = sum(g["approved_plan_died"] for g in games)
        lines.append(f"| {label} | {mean:+.2f} | {counts} | {died} | {_link(path, base)} |")
    return lines


def parser(base: str) -> list[str]:
    """The keyword parser (keywords only, as GPTHard's routing uses it) on what it was and was not
    tuned on: the first block of language-robustness/parser.txt."""
    path = "language-robustness/parser.txt"
    row = re.compile(r"^(.+): (\d+) descriptions; identity ([\d.]+%), movement ([\d.]+%), role ([\d.]+%)$")
    shown = {
        "PATH/text_train.json": "text_train.json (tuned on)",
        "PATH/text_val.json": "text_val.json (never tuned on)",
        "stress tune": "stress set, tuning part (tuned on)",
        "stress dev": "stress set, dev part (its phrasings tuned on since 2026-11-28)",
        "stress heldout": "stress set, held-out part (never tuned on)",
        "stress written": "stress set, written part (hand-written, never tuned on)",
    }
    lines = ["| descriptions | how many | identity | movement | role |", "|---|---|---|---|---|"]
    for line in (RESULTS / path).read_text().split("\n\n")[0].splitlines():
        m = row.match(line)
        if m and m.group(1) in shown:
            name, n, *rates = m.groups()
            lines.append(f"| {shown[name]} | {int(n):,} | " + " | ".join(rates) + " |")
    return lines + [
        f"\n({_link(path, base)}; the same with the text encoder's guesses: [docs/language.md]({base}docs/language.md))"
    ]


def pilot(base: str) -> list[str]:
    """The pilot's variants at equal CPU time: steps, CPU per step, dev CE at equal steps, best."""
    path = "pilot/report.txt"
    text = (RESULTS / path).read_text().splitlines()
    speed, quality = {}, {}
    for line in text:
        words = line.split()
        if len(words) >= 6 and words[1] in ("done", "running", "stopped"):
            speed[words[0]] = (int(words[2]), float(words[5]))
        elif len(words) == 8 and words[0] in speed:
            quality[words[0]] = (words[4], words[5], words[6])
    names = {
        "base": "base: multi-query (1 KV head), attention dropout 0, lr 5e-4",
        "mha": "4 KV heads (full multi-head)",
        "attndrop": "attention dropout 0.1",
        "lr1e-3": "lr 1e-3",
    }
    lines = [
        "| variant | steps in 40 CPU-min | CPU-s/step | dev at step 1,000 / 1,250 | best dev |",
        "|---|---|---|---|---|",
    ]
    for key, label in names.items():
        steps, cpu = speed[key]
        at1000, at1250, best = quality[key]
        lines.append(f"| {label} | {steps:,} | {cpu:.2f} | {at1000} / {at1250} | {best} |")
    return lines


def load(base: str) -> list[str]:
    """`ros_stress.py load`: one client against 8, per run, from the logs of results/ros-stress/."""
    one = re.compile(r"^one client: .*?([\d.]+) calls/s")
    many = re.compile(r"^8 clients: .*?([\d.]+) calls/s, +([\d.]+) steps/s.*p50 (\d+) ms, p99 (\d+) ms")
    lines = [
        "| version, checkpoint | run | one client | 8 clients | ratio (calls/s) | 8 clients' p50 / p99 |",
        "|---|---|---|---|---|---|",
    ]
    for path, label in (
        ("ros-stress/load-worker-step32000.log", "worker process, EMMA-LWM step 32,000"),
        ("ros-stress/load-worker-step17000.log", "worker process, EMMA-LWM step 17,000"),
        ("ros-stress/load-thread-step17000.log", "batch in a thread of the node, step 17,000"),
    ):
        run, single = 0, None
        for line in (RESULTS / path).read_text().splitlines():
            if m := one.match(line):
                single = float(m.group(1))
            elif (m := many.match(line)) and single is not None:
                run += 1
                calls = float(m.group(1))
                lines.append(
                    f"| {label} ({_link(path, base)}) | {run} | {single:.1f} calls/s | {calls:.1f} calls/s "
                    f"| {calls / single:.1f}x | {m.group(3)} / {m.group(4)} ms |"
                )
                single = None
    return lines


def _span(values: list[float], fmt: str = ".2f") -> str:
    """'lo-hi' of measured values (one figure when they agree at that precision)."""
    lo, hi = format(min(values), fmt), format(max(values), fmt)
    return lo if lo == hi else f"{lo}-{hi}"


STRESS_RUNS = (  # the current code's (e0942ad; 95ea3d3 changed how it reads, not what it does)
    "speed/ros-stress-load-run11.log",
    "speed/ros-stress-load-run12.log",
    "speed/ros-stress-load-run13.log",
    "speed/ros-stress-load-run14.log",
)


def speed(base: str) -> list[str]:
    """The speed goals (docs/speed.md), each as the ratio of the fast path to its baseline measured in one run,
    with the arithmetic floor beside it (results/speed/)."""
    runs = [_load(f"speed/imagination-run{i}.json") for i in (1, 2, 3)]
    lines = [
        "| what | baseline | now (default path) | ratio, each run | goal | floor (arithmetic) |",
        "|---|---|---|---|---|---|",
    ]
    goals = {1: 5.0, 16: 2.0, 64: 2.0}
    for i, row in enumerate(runs[0]["rows"]):
        batch = row["batch"]
        rows = [r["rows"][i] for r in runs]
        ratios = ", ".join(f"{r['ratio_to_reference']['speculative']:.2f}x" for r in rows)
        if all("stepwise" in r["ratio_to_reference"] for r in rows):  # a policy's imagination, a step at a time
            stepwise = ", ".join(f"{r['ratio_to_reference']['stepwise']:.2f}x" for r in rows)
            ratios += f" (a step at a time: {stepwise})"
        ref = _span([r["seconds"]["reference"] for r in rows])
        now = _span([r["seconds"]["speculative"] for r in rows])
        floor = min(r["floor_seconds"] for r in rows)
        lines.append(
            f"| imagining {batch} {'trajectory' if batch == 1 else 'trajectories'} of 32 steps "
            f"({_link('speed/imagination-run1.json', base)}, runs 1-3) "
            f"| {ref} s | {now} s | {ratios} | >= {goals[batch]:.0f}x | {floor:.4f} s |"
        )
    policy = _load("speed/policy-step.json")
    dense = policy["rows"][0]
    for row in policy["rows"][1:]:
        lines.append(
            f"| a policy training step, minibatch {row['batch']} ({_link('speed/policy-step.json', base)}) "
            f"| {dense['ms']:.1f} ms (dense, {dense['batch']}) | {row['ms']:.1f} ms | {row['ratio']:.1f}x | >= 2x "
            f"| {row['floor_ms']:.1f} ms |"
        )
    many = re.compile(r"^8 clients: .*?([\d.]+) calls/s, .*p99 (\d+) ms")
    runs = []  # (reference calls/s, p99), (speculative calls/s, p99) of each run: its first two loads
    for name in STRESS_RUNS:
        found = [m for line in (RESULTS / name).read_text().splitlines() if (m := many.match(line))]
        runs.append([(float(m.group(1)), int(m.group(2))) for m in found[:2]])
    ref = " / ".join(f"{r[0][0]:.1f} calls/s, p99 {r[0][1]} ms" for r in runs)
    now = " / ".join(f"{r[1][0]:.1f} calls/s, p99 {r[1][1]} ms" for r in runs)
    ratios = ", ".join(f"{r[1][0] / r[0][0]:.2f}x" for r in runs)
    others = ", ".join(f"[run {i}]({base}results/{name})" for i, name in enumerate(STRESS_RUNS[1:], 2))
    lines.append(
        f"| the world-model server, 8 clients ({_link(STRESS_RUNS[0], base)}, {others}) "
        f"| {ref} | {now} | {ratios} | >= 2x, p99 < 200 ms | - |"
    )
    return lines


def effort(base: str) -> list[str]:
    """Real return against the labels a person was asked for (benchmarks/human_effort.py)."""
    path = "human_effort/summary.json"
    summary = _load(path)
    budgets = sorted({b for row in summary.values() for b in row if b not in ("all", "none")}, key=int)
    head = " | ".join(
        "manual only, 0 labels (the rule-based expert labels)" if b == "0" else f"at most {b} labels" for b in budgets
    )
    learnt = any("none" in row for row in summary.values())  # the agent with no controller, where measured
    first = "manual only, no controller (learns from imagined returns) | " if learnt else ""
    lines = [
        f"| world model | {first}{head} | every imagined state labelled (Table 3) |",
        "|---" * (len(budgets) + (3 if learnt else 2)) + "|",
    ]
    for kind, name in (("emma", "EMMA-LWM"), ("observational", "Observational")):
        row = summary.get(kind)
        if row is None:
            continue
        cells = []
        for b in (["none"] if learnt else []) + [*budgets, "all"]:
            c = row.get(b)
            if c is None:
                cells.append("not measured")
                continue
            asked = "" if c["labels_asked"] is None else f"; {c['labels_asked']:.1f} asked"
            cells.append(f"{c['mean']:+.2f} ({c['low']:+.2f}, {c['high']:+.2f}){asked}")
        games = row[budgets[0]]["games"]
        lines.append(f"| {name} ({games} games) | " + " | ".join(cells) + " |")
    lines.append(f"\nMean real return over the games (95% t interval), 48 real episodes per game; {_link(path, base)}.")
    return lines


def _paired_teaching(base: str, old_path: str, new_path: str, old_name: str, new_name: str, note: str) -> list[str]:
    """Two self-teaching settings on the same games and seeds (benchmarks/human_effort.py,
    EMMA-LWM): real return of each, their paired difference, the wait and its parts."""
    import numpy as np

    from lwm_models.stats import mean_interval

    def records(name: str) -> dict:
        return {(r["model"], r["game"], r["budget"]): r for r in _load_jsonl(name)}

    old, new = records(old_path), records(new_path)
    lines = [
        f"| labels asked at most | {old_name} | {new_name} | {new_name} - {old_name}, paired "
        f"| wait, median ({old_name} / {new_name}) | learning | imagining |",
        "|---|---|---|---|---|---|---|",
    ]
    for budget in sorted({k[2] for k in new}):
        keys = sorted(k for k in new if k[2] == budget and k in old)
        a = np.array([old[k]["return"] for k in keys])
        b = np.array([new[k]["return"] for k in keys])
        cells = []
        for values in (a, b, b - a):
            m, lo, hi = mean_interval(values)
            cells.append(f"{m:+.2f} ({lo:+.2f}, {hi:+.2f})")

        def median(rows, key=None):
            return float(np.median([r["wait_seconds"] if key is None else r["seconds"][key] for r in rows]))

        before, after = [old[k] for k in keys], [new[k] for k in keys]
        parts = [f"{median(before, key):.1f} / {median(after, key):.1f} s" for key in (None, "fit", "imagine")]
        lines.append(f"| {budget} ({len(keys)} games) | " + " | ".join(cells + parts) + " |")
    lines.append(
        f"\nMean real return (95% t interval), 48 real episodes per game; {_link(old_path, base)}, "
        f"{_link(new_path, base)}. {note}"
    )
    return lines


def teaching_minibatch(base: str) -> list[str]:
    """Self-teaching with minibatches of 64 labelled states against 256."""
    return _paired_teaching(
        base,
        "human_effort/records.jsonl",
        "human_effort/records-emma-minibatch-64.jsonl",
        "minibatch 256",
        "minibatch 64",
        "The two were run on different days: the waits are not one run's.",
    )


def teaching_overlap(base: str) -> list[str]:
    """Self-teaching that imagines each round while the policy learns from the last, against the
    rounds one after the other (both on minibatches of 64)."""
    return _paired_teaching(
        base,
        "human_effort/records-emma-minibatch-64.jsonl",
        "human_effort/records-emma-overlap.jsonl",
        "in turn",
        "overlapped",
        "The two were run on different days, in one process (imagining and learning share its cores and "
        "its interpreter): the waits are not one run's, nor the real system's. Overlapped, learning counts "
        "only what the imagining did not hide.",
    )


LANGUAGE_MODELS = (
    ("emma-lwm", "EMMA-LWM"),
    ("emma-lwm-freeform", "EMMA-LWM free-form"),
    ("emma-lwm-reader", "EMMA-LWM, reader tuned"),
    ("emma-lwm-hedged", "EMMA-LWM, reader tuned, hedged"),
    ("emma-lwm-practised", "EMMA-LWM, hedged, practised"),
    ("gpthard", "GPTHard"),
    ("gpthard-hedged", "GPTHard, hedged"),
    ("observational", "Observational (reads no text)"),
)


def _source_label(source: str) -> str:
    if source == "dataset":
        return "the dataset's (human-written)"
    if source == "generated":
        return "the project's generator"
    return f"held-out {source.split(':', 1)[1]}"


def language(base: str) -> list[str]:
    """NewAll test cross-entropy by the wording of the manuals (benchmarks/language_robustness.py)."""
    path = "language-robustness/summary.json"
    summary = _load(path)
    models = [(key, name) for key, name in LANGUAGE_MODELS if key in summary["results"]]
    sources = list(dict.fromkeys(s for key, _ in models for s in summary["results"][key]))
    lines = [
        "| manuals of NewAll test | " + " | ".join(name for _, name in models) + " |",
        "|---" * (len(models) + 1) + "|",
    ]
    for source in sources:
        cells = []
        for key, _ in models:
            r = summary["results"][key].get(source)
            if r is None:
                cells.append("not measured")
                continue
            read = r.get("identity_read")
            cells.append(f"{r['cross_entropy']['total']:.3f}" + ("" if read is None else f" ({read:.0%} placed)"))
        lines.append(f"| {_source_label(source)} | " + " | ".join(cells) + " |")
    episodes = summary["settings"]["episodes"]
    lines.append(
        f"\nTotal cross-entropy on {episodes:,} NewAll test episodes (lower is better); in brackets, how often the "
        f"world model reads a description as about its true entity; {_link(path, base)}."
    )
    return lines


def read_back(base: str) -> list[str]:
    """What the system says the world model understood, against the true parse (benchmarks/read_back.py)."""
    path = "read-back/summary.json"
    summary = _load(path)
    lines = [
        "| world model | manuals | roles right (games) | movements right (entities) | descriptions placed right |",
        "|---|---|---|---|---|",
    ]
    for key, name in LANGUAGE_MODELS:
        for source, c in summary["results"].get(key, {}).items():
            placed = "-" if c["identity"] is None else f"{c['identity']:.0%}"
            lines.append(f"| {name} | {_source_label(source)} | {c['roles']:.0%} | {c['movement']:.0%} | {placed} |")
    games = len(summary["settings"]["games"])
    lines.append(f"\n{games} NewAll test games (Table 3's); {_link(path, base)}.")
    return lines


def read_back_summary(base: str) -> list[str]:
    """The read-back per world model on the dataset's text, the generator's and all held-out styles
    pooled: roles right / movements right / descriptions placed right."""
    path = "read-back/summary.json"
    summary = _load(path)
    groups = (
        ("dataset", "the dataset's"),
        ("generated", "the generator's"),
        ("stress:", "held-out free-form, 7 styles"),
    )
    lines = [
        "| world model | " + " | ".join(label for _, label in groups) + " |",
        "|---" * (len(groups) + 1) + "|",
    ]
    for key, name in LANGUAGE_MODELS:
        by_source = summary["results"].get(key)
        if by_source is None:
            continue
        cells = []
        for prefix, _ in groups:
            found = [c for source, c in by_source.items() if source.startswith(prefix)]
            games = sum(c["games"] for c in found)
            mean = {k: sum((c[k] or 0) * c["games"] for c in found) / games for k in ("roles", "movement", "identity")}
            placed = "-" if found[0]["identity"] is None else f"{mean['identity']:.0%}"
            cells.append(f"{mean['roles']:.0%} / {mean['movement']:.0%} / {placed}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    games = len(summary["settings"]["games"])
    lines.append(
        f"\nRoles right (per game) / movements right (per entity) / descriptions placed on the right entity, "
        f"{games} NewAll test games; {_link(path, base)}."
    )
    return lines


READERS = (("emma-lwm-hedged", "EMMA-LWM, reader tuned, hedged (the default)"), ("words", "the keyword parser alone"))
READING_SOURCES = (
    ("dataset", "the dataset's (human-written)"),
    ("generated", "the project's generator"),
    ("fresh", "fresh held-out, people's own words"),
    ("unusable", "no usable fact (gibberish, other games)"),
)


def before_acting(base: str) -> list[str]:
    """The manual's reading before any step (benchmarks/before_acting.py), per reader and source."""
    path = "before-acting/summary.json"
    summary = _load(path)
    lines = [
        "| reader | manuals | roles right | movements right | same reading in every order | calibration error: "
        "role / movement / assignment | questions a manual | roles right, questions answered | every role < 50% |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for key, name in READERS:
        for source, label in READING_SOURCES:
            c = summary["results"].get(key, {}).get(source)
            if c is None:
                continue
            lines.append(
                f"| {name} | {label} | {c['roles_right']:.0%} | {c['movements_right']:.0%} | {c['stable']:.0%} | "
                f"{c['ece_role']:.3f} / {c['ece_movement']:.3f} / {c['ece_assignment']:.3f} | {c['questions']:.2f} | "
                f"{c['roles_right_answered']:.0%} | {c['all_roles_below_half']:.0%} |"
            )
    lines.append(
        f"\n{summary['settings']['games']} NewAll test games drawn at random (seed {summary['settings']['seed']}); "
        f"roles right per game, movements per entity; expected calibration error over 10 bins; "
        f"{_link(path, base)}, its [reliability plot]({base}results/before-acting/summary.png)."
    )
    return lines


def before_acting_styles(base: str) -> list[str]:
    """The default reader on the fresh held-out part, per style of the description."""
    path = "before-acting/summary.json"
    cell = _load(path)["results"]["emma-lwm-hedged"]["fresh"]
    lines = [
        "| style | entities | role right | movement right | calibration error of the role |",
        "|---|---|---|---|---|",
    ]
    for style, c in cell["by_style"].items():
        lines.append(
            f"| {style} | {c['entities']} | {c['role_right']:.0%} | {c['movement_right']:.0%} | {c['ece_role']:.3f} |"
        )
    lines.append(f"\nPer entity, by the style of its description; {_link(path, base)}.")
    return lines


def before_acting_world(base: str) -> list[str]:
    """The default world model under the manual's reading, per source of the manuals."""
    path = "before-acting/summary.json"
    summary = _load(path)
    lines = [
        "| manuals | imagined reward precision | imagined termination precision | cross-entropy under the "
        "reading before any step | teacher-forced cross-entropy (updated by the episode) |",
        "|---|---|---|---|---|",
    ]
    world = summary.get("world_model", {}).get("emma-lwm-hedged", {})
    for source, label in READING_SOURCES:
        c = world.get(source)
        if c is not None:
            lines.append(
                f"| {label} | {c['reward_precision']:.2f} | {c['termination_precision']:.2f} | "
                f"{c['prior_cross_entropy']:.3f} | {c['teacher_forced_cross_entropy']:.3f} |"
            )
    episodes = summary["settings"].get("recorded episodes", 0)
    lines.append(
        f"\n{episodes} recorded NewAll test episodes, evenly spaced, each with its manual drawn from the source; "
        f"a lone imagined trajectory replays the real actions; cross-entropy as `lwm eval` reports it (obs + reward "
        f"+ done, per token); {_link(path, base)}."
    )
    return lines


REVIEW_READING = (
    ("reading-dataset", "the dataset's text"),
    ("reading-dataset-questions", "the dataset's text, questions answered"),
    ("reading-fresh", "fresh held-out, people's own words"),
    ("reading-fresh-questions", "fresh held-out, questions answered"),
)


def review_loop_reading(base: str) -> list[str]:
    """The review loop with the manual all the reviewer gives (`--teach none`), by who wrote it."""
    from lwm_models.stats import mean_interval

    lines = [
        "| the game's manual | games | real return, mean (95% t interval) | won / died / time limit / aborted "
        "| first plan's roles right | questions answered | an answer to the revised plan, p50 (max) "
        "| approved plans that died | file |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, label in REVIEW_READING:
        path = f"review-loop/{name}.jsonl"
        if not (RESULTS / path).is_file():
            continue
        games = _load_jsonl(path)
        mean, low, high = mean_interval([g["real_return"] for g in games])
        outcomes = [g["outcome"] for g in games]
        counts = " / ".join(str(outcomes.count(o)) for o in ("won", "died", "time_limit", "aborted"))
        right = sum(g["first_roles_right"] for g in games)
        asked = sum(g["questions_answered"] for g in games)
        died = sum(g["approved_plan_died"] for g in games)
        waits = sorted(s for g in games for kind, s in g["revise"] if kind == "answer")
        waited = f"{statistics.median(waits):.1f} s ({waits[-1]:.1f} s)" if waits else "-"
        lines.append(
            f"| {label} | {len(games)} | {mean:+.2f} ({low:+.2f}, {high:+.2f}) | {counts} | {right} of {len(games)} | "
            f"{asked} | {waited} | {died} | {_link(path, base)} |"
        )
    return lines


def no_controller(base: str) -> list[str]:
    """The agent learning from its world model's imagined returns alone (0 labels): Table 3's 30
    NewAll games, and the served model on 10 evenly spaced ones."""
    from lwm_models.stats import mean_interval

    lines = [
        "| world model | games | real return, no controller, 0 labels | imagined return, last round "
        "| learning time per game | file |",
        "|---|---|---|---|---|---|",
    ]
    served = ("emma-hedged", "EMMA-LWM, hedged reading (served)")
    for path, games, models in ((NO_CONTROLLER_RECORDS, "Table 3's", TABLE3_MODELS),
                                (SERVED_NO_CONTROLLER_RECORDS, "evenly spaced", (served,))):  # fmt: skip
        learnt = _load_jsonl(path)
        for kind, name in models:
            rows = [r for r in learnt if r["model"] == kind]
            if rows:
                mean, low, high = mean_interval([r["return"] for r in rows])
                imagined = sum(r["imagined"]["imagined_return"] for r in rows) / len(rows)
                secs = sum(r["learn_seconds"] for r in rows) / len(rows)
                lines.append(
                    f"| {name} | {len(rows)}, {games} | {mean:+.2f} ({low:+.2f}, {high:+.2f}) | {imagined:+.2f} "
                    f"| {secs:.0f} s | {_link(path, base)} |"
                )
    return lines


TABLES: dict[str, Callable[[str], list[str]]] = {
    "no-controller": no_controller,
    "before-acting": before_acting,
    "before-acting-styles": before_acting_styles,
    "before-acting-world": before_acting_world,
    "review-loop-reading": review_loop_reading,
    "effort": effort,
    "teaching-minibatch": teaching_minibatch,
    "teaching-overlap": teaching_overlap,
    "read-back-summary": read_back_summary,
    "language": language,
    "read-back": read_back,
    "summary": summary,
    "table1": table1,
    "table2": table2,
    "rules": rules,
    "consistency": consistency,
    "table3": table3,
    "review-loop": review_loop,
    "review-loop-variants": review_loop_variants,
    "parser": parser,
    "pilot": pilot,
    "load": load,
    "speed": speed,
}
BLOCK = re.compile(r"(<!-- table:([\w-]+) -->\n)(.*?)(<!-- /table:\2 -->)", re.S)


def render(text: str, base: str) -> str:
    """`text` with every marked table made again from results/ (links relative to `base`)."""

    def fill(match: re.Match) -> str:
        name = match.group(2)
        if name not in TABLES:
            raise SystemExit(f"results_tables: unknown table {name!r} (known: {', '.join(TABLES)})")
        return match.group(1) + "\n".join(TABLES[name](base)) + "\n" + match.group(4)

    return BLOCK.sub(fill, text)


def documents() -> list[Path]:
    found: list[Path] = []
    for pattern in DOCS:
        found += sorted(ROOT.glob(pattern))
    return found


def base_of(path: Path) -> str:
    """The relative path from `path`'s folder to the repository's root, for links."""
    depth = len(path.relative_to(ROOT).parts) - 1
    return "../" * depth


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if a table is stale")
    args = ap.parse_args(argv)
    stale = []
    for path in documents():
        text = path.read_text()
        made = render(text, base_of(path))
        if made == text:
            continue
        stale.append(str(path.relative_to(ROOT)))
        if not args.check:
            path.write_text(made)
    if args.check and stale:
        print("results_tables: stale tables in " + ", ".join(stale) + " (run scripts/results_tables.py)")
        return 1
    if stale:
        print("results_tables: rewrote " + ", ".join(stale))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The review loop on the real multi-process system: for each of N NewAll test games (the games of
`lwm agent table3 --games N`), start the launcher with its four nodes and the scripted reviewer,
let the review run to its execution report, and read the ledger and the planner's log.

Prints per game and overall: real return (mean, 95% interval over games), outcome, whether an
approved plan's shown trajectory died, time from feedback to the revised plan per feedback kind
(p50, max; language feedback: the reviewer's first answer is the true manual in other words),
the reviewer's effort per game next to its return (labels asked and given, corrected steps,
manuals written; `--teach none`: the manual is all the reviewer gives),
the /lwm/imagine calls and their overhead over the world-model server's own time, and the
comparison with Table 3's online-imitation records of the served world model (by its weights'
hash) on the same games (results/table3/records-*.jsonl).

    .venv/bin/python benchmarks/review_loop.py [--games 10] [--texts FILE ...] [--out results/review-loop/NAME.jsonl]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_nodes import domains  # noqa: E402

from lwm_models.data.splits import load_split  # noqa: E402
from lwm_models.ledger import Ledger  # noqa: E402
from lwm_models.run_dirs import LEDGER_FILE  # noqa: E402
from lwm_models.stats import mean_interval  # noqa: E402
from lwm_models.world.shipped import SHIPPED, SYSTEM_WORLD_MODEL  # noqa: E402

TEXTS = ROOT.parent / "shared" / "data" / "messenger-texts"
ANSWERED = re.compile(r"scripted human: answered .* on plan \d+ at ([\d.]+)")
SPOKEN = re.compile(r"manual feedback on plan \d+ at ([\d.]+)")
STATS = re.compile(r"imagine calls (\d+), round trip ([\d.]+) s, world-model server ([\d.]+) s")


def run_game(index: int, seed: int, args, work: Path) -> dict:
    logs = work / f"game{index}"
    ledger = logs / LEDGER_FILE
    cmd = [sys.executable, "-m", "lwm_nodes.launcher", "--scripted", "--quiet", "--split", args.split]
    cmd += ["--index", str(index), "--seed", str(seed), "--log-dir", str(logs), "--ledger", str(ledger)]
    cmd += ["--teach", args.teach] + (["--texts", *args.texts] if args.texts else [])
    cmd += ["--language"] if args.language else []
    cmd += ["--answer-questions"] if args.answer_questions else []
    cmd += ["--approve-return", str(args.approve_return)]
    cmd += ["--constrained"] if args.constrained else ["--no-constrained"]
    cmd += ["--constrained-learning"] if args.constrained_learning else []
    if args.iterations:
        cmd += ["--iterations", str(args.iterations)]
    if args.config:
        cmd += ["--config", str(args.config)]
    if args.checkpoint:
        cmd += ["--checkpoint", str(args.checkpoint)]
    env = {
        **os.environ,
        "ROS_DOMAIN_ID": str(args.domain or domains.claim()),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
    }
    began = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        out, _ = proc.communicate(timeout=args.timeout)
    except subprocess.TimeoutExpired:
        # SIGTERM: the launcher stops its nodes (each in a session of its own) before it exits; they
        # would otherwise go on answering the next game's.
        proc.terminate()
        try:
            proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
        raise SystemExit(
            f"game {index}: no report within {args.timeout:.0f} s; its launcher and nodes were stopped"
        ) from None
    wall = time.monotonic() - began
    if proc.returncode != 0:
        raise SystemExit(f"game {index}: launcher exited {proc.returncode}:\n{out[-2000:]}")
    records = Ledger(ledger).history()
    report = next(r["payload"] for r in records if r["kind"] == "report")
    plans = {r["payload"]["plan_id"]: r["payload"] for r in records if r["kind"] == "plan"}
    approved = [
        plans[r["payload"]["plan_id"]]
        for r in records
        if r["kind"] == "feedback" and r["payload"]["decision"] == "approve"
    ]
    revise = []  # (feedback kind, seconds from the feedback's record to the next plan's)
    for i, r in enumerate(records):
        if r["kind"] == "feedback" and r["payload"]["decision"] not in ("approve", "abort"):
            kind, seen = r["payload"]["decision"], ("plan",)
        elif r["kind"] == "labels":  # what the reviewer sees next: the next round's states, or the plan
            kind, seen = "labels", ("label_request", "plan")
        else:
            continue
        nxt = next((q for q in records[i + 1 :] if q["kind"] in seen), None)
        if nxt is not None:
            said = kind if kind != "labels" else f"labels -> {nxt['kind'].replace('_', ' ')}"
            revise.append((said, nxt["time"] - r["time"]))
    human_log = (logs / "human.log").read_text()
    for kind, pattern in (("manual", SPOKEN), ("answer", ANSWERED)):
        for said in map(float, pattern.findall(human_log)):
            # From the human node's publication on /feedback/manual to the plan under the new manual.
            nxt = next((q for q in records if q["kind"] == "plan" and q["time"] > said), None)
            if nxt is not None and nxt["payload"]["reason"] == "manual":
                revise.append((kind, nxt["time"] - said))
    m = STATS.search((logs / "planner.log").read_text())
    # The reviewer's effort: every state a label request asked about, the labels given, the
    # corrected steps and the manuals written (the scripted reviewer answers all it is asked).
    feedback = [r["payload"] for r in records if r["kind"] == "feedback"]
    # What the first plan rested on: the roles the agent acted on, against the game's.
    first = plans[min(plans)] if plans else {}
    truth = {e.identity: e.role for e in load_split(args.split)[index].entities}
    return {
        "game": index,
        "seed": seed,
        "real_return": report["real_return"],
        "outcome": report["outcome"],
        "reviews_asked": report.get("reviews_asked", 0),
        "plans": len(plans),
        "labels_asked": sum(r["payload"]["states"] for r in records if r["kind"] == "label_request"),
        "labels_given": sum(r["payload"]["labels"] for r in records if r["kind"] == "labels"),
        "corrections": sum(len(f.get("corrections", [])) for f in feedback if f["decision"] == "corrections"),
        "manuals_written": sum(
            1 for r in records if r["kind"] == "manual" and r["payload"].get("source") not in ("", "env")
        ),
        "first_roles_right": bool(first.get("roles"))
        and all(e["role"] == truth[e["identity"]] for e in first["roles"]),
        "questions_asked": len(first.get("questions", [])),
        "questions_answered": len(ANSWERED.findall(human_log)),
        "approved_plan_died": any(any(x < 0 for x in p["rewards"]) for p in approved),
        "revise": revise,
        "imagine_calls": int(m.group(1)) if m else None,
        "imagine_round_trip_s": float(m.group(2)) if m else None,
        "imagine_server_s": float(m.group(3)) if m else None,
        "wall_s": round(wall, 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--games", type=int, default=10, help="test games, spread as lwm agent table3 --games picks them")
    p.add_argument("--split", default="newall-test")
    p.add_argument("--seed", type=int, default=0, help="episode seed of every game")
    p.add_argument("--teach", default="online_il", choices=["online_il", "filtered_bc", "corrections", "none"])
    p.add_argument(
        "--approve-return",
        type=float,
        default=1.0,
        help="the scripted reviewer approves at once a safe plan imagining this return (above 1.5: it teaches first)",
    )
    p.add_argument(
        "--language",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the scripted reviewer first gives language feedback (the true manual in other words)",
    )
    p.add_argument(
        "--iterations", type=int, default=None, help="the planner's learning rounds (default: the launcher's)"
    )
    p.add_argument(
        "--constrained",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="the plans a person reviews are imagined under the game's rules (decoding constraints)",
    )
    p.add_argument(
        "--constrained-learning",
        action=argparse.BooleanOptionalAction,
        default=False,
        help="the planner's learning rounds are imagined under the game's rules too",
    )
    default_texts = [str(TEXTS / "text_train.json"), str(TEXTS / "text_val.json")] if TEXTS.is_dir() else None
    p.add_argument(
        "--texts",
        nargs="*",
        default=default_texts,
        help="description files of the game's manuals, or stress:fresh (the fresh held-out part, people's own words)",
    )
    p.add_argument(
        "--answer-questions",
        action="store_true",
        help="the scripted reviewer answers the question a plan asks about the manual's reading first (the truth)",
    )
    p.add_argument(
        "--records",
        type=Path,
        default=None,
        help="Table 3 records of the same games to compare with (lwm agent table3 --records; default: every "
        "results/table3/records-*.jsonl, of which the served world model's)",
    )
    p.add_argument("--out", type=Path, default=None, help="JSONL of per-game results (appended)")
    p.add_argument("--logs", type=Path, default=None, help="keep each game's node logs and ledger here")
    p.add_argument(
        "--domain", type=int, default=0, help="ROS_DOMAIN_ID of the benchmark's systems (0: one no other run holds)"
    )
    p.add_argument("--timeout", type=float, default=900.0, help="seconds per game")
    p.add_argument(
        "--config",
        type=Path,
        default=None,
        help="the nodes' parameter files (run_nodes.sh --config; default: the package's)",
    )
    p.add_argument(
        "--checkpoint", type=Path, default=None, help="the world model the server serves (default: the system's)"
    )
    args = p.parse_args()
    n = len(load_split(args.split))
    games = np.linspace(0, n - 1, min(args.games, n)).round().astype(int)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for g in games:
            row = run_game(int(g), args.seed, args, args.logs or Path(tmp))
            rows.append(row)
            print(json.dumps(row), flush=True)
            if args.out:
                with args.out.open("a") as f:
                    f.write(json.dumps(row) + "\n")
    r = np.array([x["real_return"] for x in rows])
    _, lo, hi = mean_interval(r)
    print(f"\nreal return over {len(r)} games: {r.mean():+.2f} (95% t interval {lo:+.2f}..{hi:+.2f})")
    print("outcomes:", {o: sum(x["outcome"] == o for x in rows) for o in ("won", "died", "time_limit", "aborted")})
    print(f"approved plans whose shown trajectory died: {sum(x['approved_plan_died'] for x in rows)}")
    print(
        f"first plan's roles right: {sum(x['first_roles_right'] for x in rows)} of {len(rows)}; questions asked "
        f"{sum(x['questions_asked'] for x in rows)}, answered {sum(x['questions_answered'] for x in rows)}"
    )
    print("per game: real return, then the reviewer's effort (labels asked / given, corrected steps, manuals)")
    for x in rows:
        print(
            f"  game {x['game']:4d}: {x['real_return']:+.2f} {x['outcome']:10s} labels {x['labels_asked']:3d} / "
            f"{x['labels_given']:3d}, corrections {x['corrections']:2d}, manuals {x['manuals_written']}"
        )
    asked = np.array([x["labels_asked"] for x in rows])
    print(f"labels asked per game: mean {asked.mean():.1f}, max {asked.max()}")
    kinds = sorted({k for x in rows for k, _ in x["revise"]})
    for k in kinds:
        t = np.array([s for x in rows for kk, s in x["revise"] if kk == k])
        print(f"feedback -> revised plan, {k}: p50 {np.median(t):.2f} s, max {t.max():.2f} s ({len(t)})")
    calls = [x for x in rows if x["imagine_calls"]]
    if calls:
        c = sum(x["imagine_calls"] for x in calls)
        over = sum(x["imagine_round_trip_s"] - x["imagine_server_s"] for x in calls)
        server = sum(x["imagine_server_s"] for x in calls)
        print(
            f"/lwm/imagine: {c} calls, overhead {over:.1f} s over {server:.1f} s in the world-model server "
            f"({over / c * 1000:.2f} ms per call, {over / server:.1%})"
        )
    files = [args.records] if args.records else sorted((ROOT / "results" / "table3").glob("records-*.jsonl"))
    # Only records of the world model the world-model server served (by its weights' hash).
    served = args.checkpoint or SHIPPED[SYSTEM_WORLD_MODEL]
    shipped = json.loads((served / "config.json").read_text()).get("sha256", "")
    table = {
        rec["game"]: rec["return"]
        for path in files if path.is_file()
        for rec in map(json.loads, path.read_text().splitlines())
        if rec["setting"] == "online_il" and rec["split"] == args.split and rec.get("checkpoint") == shipped
    }  # fmt: skip
    if not table:
        print(f"no Table 3 records of the world model served ({shipped[:12]}) in {', '.join(map(str, files))}")
    both = [x for x in rows if x["game"] in table]
    if both:
        t3 = np.mean([table[x["game"]] for x in both])
        mine = np.mean([x["real_return"] for x in both])
        print(
            f"Table 3 (online IL, the served {served.name}, 48 episodes per game) on the same {len(both)} of "
            f"{len(rows)} games: {t3:+.2f}; review loop: {mine:+.2f}; difference {mine - t3:+.2f}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

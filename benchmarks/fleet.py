"""A fleet under review on one world-model server (issue 34): 1, 4 and 8 agents.

For each fleet size N, the launcher starts one world-model server and N agents (`--agents N`), each
with its environment, planner and scripted reviewer in its own namespace, playing the same NewAll
test game from seeds SEED, SEED+1, ...; agent1's reviewer first gives language feedback to every
agent (the true manual in other words, on /feedback/manual), and each reviewer then reviews its
agent's plans to the execution's report. Manuals are drawn from the dataset's human-written
descriptions when they are at hand (--texts), as the shipped models were trained: the project's
generator's text is one the shipped EMMA-LWM reads poorly (docs/language.md). With --server-host,
the world-model server runs in one network namespace and the agents in another (two simulated
hosts, traffic over a veth pair: needs root).

Prints and records, per fleet size: real return per agent (mean and each) and wins, reviews per
minute (reports over the time from the first plan to the last report), the agents whose review
took the fleet's manual and those that planned under it, the world-model server's calls (and per
second of the run) with their latency (p50, p99) and the mean batch of its one-shot calls (its load
report at shutdown), and the wall time.

    flock /tmp/lwm-heavy.lock .venv/bin/python benchmarks/fleet.py --agents 1 4 8 --out results/fleet/fleet.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from imagination import git_commit  # noqa: E402  (benchmarks/ is on sys.path when run as a script)
from lwm_nodes import domains, netns  # noqa: E402

from lwm_models.ledger import Ledger  # noqa: E402
from lwm_models.run_dirs import LEDGER_FILE  # noqa: E402

LOAD = re.compile(r"imagine load: (\{.*\})")
SHARED_TEXTS = ROOT.parent / "shared" / "data" / "messenger-texts"
TEXTS = [SHARED_TEXTS / "text_train.json", SHARED_TEXTS / "text_val.json"]


def launcher(*args: str) -> list[str]:
    return [sys.executable, "-m", "lwm_nodes.launcher", "--quiet", "--max-restarts", "0", *args]


def run_fleet(n: int, args, work: Path) -> dict:
    logs = work / f"agents{n}"
    common = ["--index", str(args.index), "--seed", str(args.seed), "--agents", str(n), "--ready-timeout", "600"]
    common += ["--keys-file", str(work / "keys.json")] + (["--texts", *args.texts] if args.texts else [])
    common += ["--iterations", str(args.iterations)] if args.iterations else []
    common += ["--futures", str(args.futures)] if args.futures else []
    agents = ["--scripted", "--language", "--log-dir", str(logs), *common]
    env = {**os.environ, "ROS_DOMAIN_ID": str(domains.claim()), "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}
    began = time.monotonic()
    server = None
    if args.server_host:
        hosts = netns.two_hosts()
        a, b = hosts.__enter__()
        env.update(netns.HOST_ENV)
        only_server = ["--only", "world_model", "--no-human", "--log-dir", str(logs / "server"), *common]
        server = subprocess.Popen(
            netns.in_host(a, launcher(*only_server)),
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        for line in server.stdout:
            if "nodes ready" in line or "did not become ready" in line:
                break
        cmd = netns.in_host(b, launcher("--only", "env,planner,human", *agents))
    else:
        cmd = launcher(*agents)
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        out, _ = proc.communicate(timeout=args.timeout)
        finished = proc.returncode == 0
    except subprocess.TimeoutExpired:  # an agent's review never ended: stop the fleet, keep what it did
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
        finished = False
    finally:
        if server is not None:
            server.send_signal(signal.SIGINT)
            server.communicate(timeout=60)
            hosts.__exit__(None, None, None)
    wall = time.monotonic() - began
    names = [""] if n == 1 else [f"agent{i + 1}" for i in range(n)]
    per_agent, first_plan, last_report = [], [], []
    fleet_manual = None
    for name in names:
        path = logs / name / LEDGER_FILE
        records = Ledger(path, read_only=True).history() if path.is_file() else []
        report = next((r for r in records if r["kind"] == "report"), None)
        manuals = [r["payload"] for r in records if r["kind"] == "manual" and r["payload"]["source"] == "human"]
        fleet_manual = fleet_manual or (manuals[0]["descriptions"] if manuals else None)
        took = any(r["kind"] == "manual" and r["payload"]["descriptions"] == fleet_manual for r in records)
        planned = any(r["kind"] == "plan" and r["payload"]["manual"] == fleet_manual for r in records)
        first_plan += [r["time"] for r in records if r["kind"] == "plan"][:1]
        row = {"agent": name or "the agent", "seed": args.seed + len(per_agent), "reported": report is not None}
        if report is None:  # why it did not finish, in its planner's words
            planner_log = logs / f"{name + '.' if name else ''}planner.log"
            failed = [line for line in planner_log.read_text().splitlines() if "job failed" in line]
            row["failure"] = failed[-1].split("]: ", 1)[-1] if failed else "no report in the time given"
        else:
            last_report.append(report["time"])
            row.update(real_return=report["payload"]["real_return"], outcome=report["payload"]["outcome"])
        row.update(
            plans=sum(r["kind"] == "plan" for r in records),
            took_fleet_manual=took,  # its review was still open when the manual came
            planned_under_fleet_manual=planned,
        )
        per_agent.append(row)
    server_log = (logs / "server" if args.server_host else logs) / "world_model.log"
    found = LOAD.findall(server_log.read_text())
    load = json.loads(found[-1]) if found else {}
    minutes = (max(last_report) - min(first_plan)) / 60 if last_report and first_plan else 0
    returns = [a["real_return"] for a in per_agent if a["reported"]]
    return {
        "agents": n,
        "finished": finished and len(returns) == n,
        "launcher_output_tail": out[-2000:] if not finished else "",
        "mean_real_return": round(float(np.mean(returns)), 3) if returns else None,
        "per_agent": per_agent,
        "reports": len(returns),
        "won": sum(a.get("outcome") == "won" for a in per_agent),
        "reviews_per_minute": round(len(returns) / minutes, 2) if minutes > 0 else None,
        "took_fleet_manual": sum(a["took_fleet_manual"] for a in per_agent),
        "planned_under_fleet_manual": sum(a["planned_under_fleet_manual"] for a in per_agent),
        "world_model": load,
        "calls_per_second": round(load.get("calls", 0) / wall, 1) if load else None,
        "wall_s": round(wall, 1),
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--agents", type=int, nargs="+", default=[1, 4, 8], help="fleet sizes to run, one after another")
    p.add_argument("--index", type=int, default=0, help="NewAll test game every agent plays")
    p.add_argument("--seed", type=int, default=0, help="agent k plays seed SEED + k - 1")
    p.add_argument(
        "--iterations", type=int, default=None, help="the planners' learning rounds from each manual (default: theirs)"
    )
    p.add_argument("--futures", type=int, default=None, help="sampled futures shown with each plan (default: theirs)")
    p.add_argument(
        "--texts",
        nargs="+",
        default=[str(t) for t in TEXTS if t.is_file()] or None,
        help="human-written description files for the manuals and the reviewer's rewording (default: the "
        "dataset's, when present; else the project's generator)",
    )
    p.add_argument(
        "--server-host", action="store_true", help="the world-model server in a network namespace of its own"
    )
    p.add_argument(
        "--timeout", type=float, default=900.0, help="seconds one fleet may take; then it is stopped and recorded as is"
    )
    p.add_argument("--out", type=Path, default=None, help="write the figures here (JSON)")
    args = p.parse_args()
    if args.server_host and (why := netns.unavailable()):
        p.error(f"--server-host: {why}")
    rows = []
    with tempfile.TemporaryDirectory(prefix="lwm-fleet-") as tmp:
        for n in args.agents:
            row = run_fleet(n, args, Path(tmp))
            rows.append(row)
            write(args, rows)  # after each fleet: a later one that fails loses nothing
            wm = row["world_model"]
            each = ", ".join(f"{a['real_return']:+.2f}" if a["reported"] else "none" for a in row["per_agent"])
            for a in row["per_agent"]:
                if not a["reported"]:
                    print(f"{n} agents: {a['agent']} did not report: {a['failure']}", flush=True)
            mean = "none" if row["mean_real_return"] is None else f"{row['mean_real_return']:+.2f}"
            print(
                f"{n} agent(s): {row['reports']} reported, mean real return {mean} ({each}); "
                f"won {row['won']}/{n}; {row['reviews_per_minute']} reviews/min; took the fleet's manual "
                f"{row['took_fleet_manual']}/{n}, planned under it {row['planned_under_fleet_manual']}/{n}; "
                f"imagine calls {wm.get('calls')} ({row['calls_per_second']}/s), "
                f"p50 {wm.get('latency p50 ms')} ms, p99 {wm.get('latency p99 ms')} ms, "
                f"mean one-shot batch {wm.get('mean batch')}; wall {row['wall_s']:.0f} s",
                flush=True,
            )
    return 0 if all(r["finished"] for r in rows) else 1


def write(args, rows: list[dict]) -> None:
    if not args.out:
        return
    record = {
        "command": " ".join([Path(sys.executable).name, *sys.argv]),
        "commit": git_commit(),
        "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()},
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "fleets": rows,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    raise SystemExit(main())

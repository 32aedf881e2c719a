"""Real return against a person's effort: what a few labels buy, for EMMA-LWM and Observational.

For each NewAll test game (Table 3's games and manuals), each world model and each label budget,
the warm-start policy teaches itself in imagination from the world model's reading of the manual
(lwm_models/agent/self_teaching.py), asking the simulated person (the expert with the true manual,
as in Table 3) for at most that many labels, then plays the real game 48 times (each start
twice, argmax actions). Budget 0 is the manual alone. The "every state" column is Table 3's online
imitation (the simulated person labels every imagined state) from its records, for the same games.

    .venv/bin/python benchmarks/human_effort.py --data data/human-newall-test --games 10 \
        --records results/human_effort/records.jsonl

Records are appended one per (model, game, budget), so a run can stop and resume; `--from-records`
only makes the summary, the table and the plot. The summary (`--summary`) has the shape
{model: {budget: {"mean", "low", "high", "games", "labels_asked"}}} with budget "all" for every state
and "none" for the agent with no controller: it learns from the world model's imagined returns alone,
no labels (Table 3's `imagined_returns` records, results/imagined-returns/).
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parent.parent
TABLE3 = ROOT / "results" / "table3"
EVERY_STATE = {
    "emma": TABLE3 / "records-30-games-emma-lwm.jsonl",
    "observational": TABLE3 / "records-30-games-observational.jsonl",
}
# The agent that learns from imagined returns alone, no controller and no labels (Table 3's
# `imagined_returns` setting, lwm_models/agent/imagined_returns.py), on the same games.
NO_CONTROLLER = ROOT / "results" / "imagined-returns" / "records-30-games-newall.jsonl"


def run(args: argparse.Namespace) -> list[dict]:
    from tqdm import tqdm

    from lwm_models.agent.expert import expert_actions, role_ids
    from lwm_models.agent.imaginer import LocalImaginer
    from lwm_models.agent.learning import evaluate_real, start_observations
    from lwm_models.agent.policy import load_policy
    from lwm_models.agent.policy import policy_manual as read_policy_manual
    from lwm_models.agent.self_teaching import Teaching, teach
    from lwm_models.agent.table3 import table3_games
    from lwm_models.data.dataset import TrajectoryDataset
    from lwm_models.world.checkpoint import load_checkpoint
    from lwm_models.world.frozen_text import FrozenTextEncoder
    from lwm_models.world.shipped import SHIPPED_POLICY

    torch.set_num_threads(args.threads)
    encoder = FrozenTextEncoder()
    warm = load_policy(args.policy or SHIPPED_POLICY)
    ds = TrajectoryDataset(args.data, args.split)
    episode_games = np.asarray(ds.episode_games)
    # Teaching's settings given on the command line; the others keep Teaching's defaults.
    given = {"batch": args.batch} if args.batch else {}
    if args.overlap is not None:
        given["overlap"] = args.overlap
    setting = {
        k: v
        for k, v in Teaching(args.rounds, args.episodes, args.grad_steps, **given).__dict__.items()
        if k not in ("label_budget", "per_round")
    }
    done = set()
    if args.records and args.records.is_file():
        earlier = [r for r in map(json.loads, args.records.open()) if r]
        other = [r for r in earlier if r.get("teaching") != setting]
        if other:  # one file, one teaching setting: resuming must not mix two into one summary
            theirs = other[0].get("teaching")
            sys.exit(f"{args.records} holds records of another teaching setting ({theirs}); use another --records")
        done = {(r["model"], r["game"], r["budget"]) for r in earlier}
    models = {}
    for spec in args.models:
        name, _, path = spec.partition("=")
        models[name] = load_checkpoint(path)
    todo = [
        (name, g, budget)
        for g in table3_games(len(ds.games), args.games)
        for name in models
        for budget in args.budgets
        if (name, g, budget) not in done
    ][: args.max_runs]
    records = []
    for name, g, budget in tqdm(todo, desc="human effort", disable=args.no_progress):
        world, config = models[name]
        game = ds.games[g]
        manual = ds[int(np.flatnonzero(episode_games == g)[0])].manual
        seed = args.seed + g
        truth = role_ids(game)

        def person(hist, obs, steps, traj, round_no, truth=truth, seed=seed) -> np.ndarray:
            return np.asarray([expert_actions(o[None], truth, int(s) + 1, seed)[0] for o, s in zip(obs, steps)])

        imaginer = LocalImaginer(world, world.read_manual(manual, encoder, list(game.triples)))
        policy_manual = read_policy_manual(manual, encoder)
        policy = copy.deepcopy(warm)
        per_round = max(Teaching.per_round, -(-budget // args.rounds))  # a large budget can be spent
        teaching = Teaching(
            args.rounds, args.episodes, args.grad_steps, label_budget=budget, per_round=per_round, **given
        )
        began = time.perf_counter()
        result = teach(policy, imaginer, policy_manual, start_observations(game, seed), teaching, person, seed)
        waited = time.perf_counter() - began
        real = evaluate_real(policy, game, policy_manual, 48, seed)
        summary = result.summary()
        record = {
            "model": name,
            "split": args.split,
            "game": g,
            "seed": seed,
            "budget": budget,
            "return": real.mean,
            "wins": real.wins,
            "deaths": real.deaths,
            "labels_asked": summary["asked"],
            "roles_right": summary["assignment"] == [int(x) for x in truth],
            # what the expert acts on: which entity is the message and which the goal
            "targets_right": summary["assignment"][1:] == [int(x) for x in truth[1:]],
            "roles_p": summary["p"],
            "wait_seconds": round(waited, 2),
            "seconds": summary["seconds"],
            "teaching": setting,
            "per_round": per_round,
            "threads": args.threads,
            "checkpoint": config.get("sha256"),
        }
        records.append(record)
        if args.records:
            args.records.parent.mkdir(parents=True, exist_ok=True)
            with args.records.open("a") as f:
                f.write(json.dumps(record) + "\n")
    return records


def table3_returns(path: Path | None, setting: str, model: str, games: set[int], split: str) -> list[float]:
    """The real returns a Table 3 records file holds for `setting` and `model` on these games."""
    if path is None or not path.is_file():
        return []
    rows = [json.loads(line) for line in path.open() if line.strip()]
    wanted = {"setting": setting, "model": model, "split": split}
    return [r["return"] for r in rows if all(r[k] == v for k, v in wanted.items()) and r["game"] in games]


def summarize(records: list[dict], split: str) -> dict:
    from lwm_models.stats import mean_interval

    # Only the games every model and budget has a record of: each cell is over the same games.
    cells = {(r["model"], r["budget"]) for r in records}
    have = {(r["game"], r["model"], r["budget"]) for r in records}
    complete = {g for g, _, _ in have if all((g, *c) in have for c in cells)}
    records = [r for r in records if r["game"] in complete]
    out: dict[str, dict] = {}
    for model in sorted({r["model"] for r in records}):
        mine = [r for r in records if r["model"] == model]
        games = {r["game"] for r in mine}
        out[model] = {}
        for budget in sorted({r["budget"] for r in mine}):
            rows = [r for r in mine if r["budget"] == budget]
            mean, lo, hi = mean_interval([r["return"] for r in rows])
            out[model][str(budget)] = {
                "mean": round(mean, 4),
                "low": round(lo, 4),
                "high": round(hi, 4),
                "games": len(rows),
                "labels_asked": round(float(np.mean([r["labels_asked"] for r in rows])), 2),
                "roles_right": sum(r["roles_right"] for r in rows),
                "targets_right": sum(r.get("targets_right", r["roles_right"]) for r in rows),
                "wait_seconds_median": round(float(np.median([r["wait_seconds"] for r in rows])), 2),
            }
        # "all": every imagined state labelled (Table 3's online imitation); "none": no controller
        # and no labels, the agent learning from imagined returns alone.
        for key, path, setting in (("all", EVERY_STATE.get(model), "online_il"),
                                   ("none", NO_CONTROLLER, "imagined_returns")):  # fmt: skip
            found = table3_returns(path, setting, model, games, split)
            if len(found) == len(games) and len(found) > 1:
                mean, lo, hi = mean_interval(found)
                out[model][key] = {"mean": round(mean, 4), "low": round(lo, 4), "high": round(hi, 4),
                                   "games": len(found), "labels_asked": None}  # fmt: skip
    return out


def print_table(summary: dict) -> None:
    budgets = sorted(
        {b for m in summary.values() for b in m},
        key=lambda b: (b != "none", b == "all", 0 if b in ("all", "none") else int(b)),
    )
    print("real return (95% t interval over games) against the labels a person was asked for, NewAll test")
    named = {"all": "every state", "none": "no controller"}
    print(f"{'model':<14}" + "".join(f"  {named.get(b, b + ' labels'):>32}" for b in budgets))
    for model, row in summary.items():
        cells = []
        for b in budgets:
            c = row.get(b)
            if c is None:
                cells.append(f"  {'-':>32}")
                continue
            asked = "" if c["labels_asked"] is None else f", asked {c['labels_asked']:.1f}"
            cells.append("  " + f"{c['mean']:+.2f} ({c['low']:+.2f}, {c['high']:+.2f}){asked}".rjust(32))
        print(f"{model:<14}" + "".join(cells))


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    for model, row in summary.items():
        budgets = [b for b in row if b not in ("all", "none")]
        xs = [max(row[b]["labels_asked"], 0.5) for b in budgets]
        ys = [row[b]["mean"] for b in budgets]
        err = [[row[b]["mean"] - row[b]["low"] for b in budgets], [row[b]["high"] - row[b]["mean"] for b in budgets]]
        line = ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, label=f"{model}: self-teaching")
        if "all" in row:
            ax.axhline(row["all"]["mean"], color=line[0].get_color(), ls="--", label=f"{model}: every state labelled")
        if "none" in row:
            ax.axhline(
                row["none"]["mean"], color=line[0].get_color(), ls="-.", label=f"{model}: no controller, 0 labels"
            )
    ax.axhline(0.62, color="grey", ls=":", label="paper, EMMA-LWM, every state (0.62)")
    ax.set_xscale("log")
    ax.set_xlabel("labels the person was asked for, per game (mean; 0 drawn at 0.5)")
    ax.set_ylabel("real return (48 episodes a game)")
    ax.set_title("What a person's labels buy (NewAll test)")
    ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", type=Path, default=ROOT / "data" / "human-newall-test", help="dataset with the split")
    p.add_argument("--split", default="newall-test")
    p.add_argument("--games", type=int, default=10, help="games (every k-th of Table 3's 30)")
    p.add_argument(
        "--models",
        nargs="+",
        default=[
            f"emma={ROOT / 'lwm_models/checkpoints/emma-lwm'}",
            f"observational={ROOT / 'lwm_models/checkpoints/observational'}",
        ],  # fmt: skip
        help="NAME=CHECKPOINT of each world model",
    )
    p.add_argument("--budgets", type=int, nargs="+", default=[0, 10, 30, 100], help="label budgets per game")
    p.add_argument("--rounds", type=int, default=10)
    p.add_argument("--episodes", type=int, default=32)
    p.add_argument("--grad-steps", type=int, default=20)
    p.add_argument("--batch", type=int, default=None, help="labelled states per minibatch step (default: Teaching's)")
    p.add_argument(
        "--overlap",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="imagine each round while the policy learns from the last (default: Teaching's)",
    )
    p.add_argument("--policy", type=Path, default=None, help="warm-start policy (default: shipped)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1, help="torch threads (1: records reproduce)")
    p.add_argument("--records", type=Path, default=None, help="append records here (and resume from it)")
    p.add_argument("--from-records", type=Path, nargs="+", default=None, help="only summarize these records")
    p.add_argument("--summary", type=Path, default=None, help="write the summary JSON here")
    p.add_argument("--plot", type=Path, default=None, help="write the plot (PNG) here")
    p.add_argument("--max-runs", type=int, default=None, help="stop after this many new records (run in chunks)")
    p.add_argument("--no-progress", action="store_true")
    args = p.parse_args(argv)
    if args.from_records:
        records = [json.loads(line) for path in args.from_records for line in path.open() if line.strip()]
    else:
        if not (args.data / "index.json").is_file():
            p.error(f"{args.data}: no dataset (make one with lwm data generate --splits {args.split})")
        records = run(args)
        if args.records:
            records = [json.loads(line) for line in args.records.open() if line.strip()]
    summary = summarize(records, args.split)
    print_table(summary)
    if args.summary:
        args.summary.parent.mkdir(parents=True, exist_ok=True)
        args.summary.write_text(json.dumps(summary, indent=2) + "\n")
    if args.plot:
        plot(summary, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())

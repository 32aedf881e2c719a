"""The read-back's accuracy (issue 30): what the system tells a person the world model understood
of each entity before any plan, against the game's true parse.

For each NewAll test game (Table 3's 30, evenly spaced over the split), each world model and each
manual source, the agent's probes are imagined exactly as before a plan (lwm_models/agent/roles.py:
an avatar seeking one entity and then another, 8 trajectories per ordering, from the game's real
first boards), and three read-backs are scored:

- roles: the most probable role assignment is the true one (per game);
- movement: how the probes moved each entity (comes toward you / moves away from you / stays put)
  is its true movement (chaser / fleeing / immovable; per entity);
- identity: the entity the world model reads each description as about is the one it describes
  (lwm_models/world/reading.py; per description).

Manual sources are those of benchmarks/language_robustness.py: the dataset's (the first episode of
the game), the project's generator, or a held-out stress-set style.

    flock /tmp/lwm-heavy.lock env OMP_NUM_THREADS=1 .venv/bin/python benchmarks/read_back.py \\
        --data data/human-newall-test --models emma-lwm observational --sources dataset generated stress:casual
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.agent.expert import role_ids  # noqa: E402
from lwm_models.agent.imaginer import LocalImaginer  # noqa: E402
from lwm_models.agent.learning import start_observations  # noqa: E402
from lwm_models.agent.roles import believe  # noqa: E402
from lwm_models.agent.table3 import TABLE3_GAMES, table3_games  # noqa: E402
from lwm_models.agent.understood import SAID_OF  # noqa: E402
from lwm_models.data.dataset import TrajectoryDataset, dataset_source_problem  # noqa: E402
from lwm_models.messenger.constants import IDENTITIES  # noqa: E402
from lwm_models.text.stress import manual_sources, source_pools  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint  # noqa: E402
from lwm_models.world.reading import read_identities  # noqa: E402

SPLIT = "newall-test"
SOURCES = manual_sources()
OUT = ROOT / "results" / "read-back" / "summary.json"


def manual_of(ds: TrajectoryDataset, game_index: int, source: str, seed: int) -> tuple[list[str], list[tuple]]:
    """The game's manual from `source` and the true triple of each description."""
    episode = ds[int(np.flatnonzero(np.asarray(ds.episode_games) == game_index)[0])]
    pools = source_pools(source, seed)
    if pools is None:
        return list(episode.manual), list(episode.parse)
    rng = np.random.default_rng([seed, game_index])
    triples = list(episode.parse)  # the dataset's order of the entities, re-worded
    return pools.draw(SPLIT, triples, rng), triples


def reads_text(model) -> bool:
    return model.reads_text or model.route is not None


def score(model, encoder, ds: TrajectoryDataset, game_index: int, source: str, seed: int, samples: int) -> dict:
    game = ds.games[game_index]
    manual, triples = manual_of(ds, game_index, source, seed)
    imaginer = LocalImaginer(model, model.read_manual(manual, encoder, triples))
    belief = believe(imaginer, start_observations(game, seed), samples, seed)
    truth = {IDENTITIES[e.identity]: e for e in game.entities}
    movement = [belief.movements.get(i) == SAID_OF[e.movement] for i, e in truth.items()]
    read = read_identities(model, encoder, manual)
    return {
        "game": game_index,
        "source": source,
        "roles_right": bool(tuple(belief.best()[0]) == tuple(int(i) for i in role_ids(game))),
        "p": round(belief.best()[1], 3),
        "movement_right": int(sum(movement)),
        "movements": {e.identity: belief.movements.get(i) for i, e in truth.items()},
        "identity_right": int(sum(r == t[0] for r, t in zip(read, triples))) if reads_text(model) else None,
    }


def summarise(records: list[dict]) -> dict:
    """Per model (in the order they first appear) and source (in SOURCES' order): the share of
    games whose roles were read right, and of entities whose movement and description were."""
    out: dict = {}
    for r in in_order(records):
        cell = out.setdefault(r["model"], {}).setdefault(
            r["source"], {"games": 0, "roles": 0, "movement": 0, "identity": 0}
        )
        cell["games"] += 1
        cell["roles"] += int(r["roles_right"])
        cell["movement"] += r["movement_right"]
        cell["identity"] = None if r["identity_right"] is None else cell["identity"] + r["identity_right"]
    for by_source in out.values():
        for cell in by_source.values():
            n = cell["games"]
            cell["roles"] = cell["roles"] / n
            cell["movement"] = cell["movement"] / (3 * n)
            cell["identity"] = None if cell["identity"] is None else cell["identity"] / (3 * n)
    return out


def in_order(records: list[dict]) -> list[dict]:
    """The records by model (first appearance) and source (SOURCES' order), games in their order:
    a run that re-measures one source puts its records back in place."""
    models = list(dict.fromkeys(r["model"] for r in records))
    return sorted(records, key=lambda r: (models.index(r["model"]), SOURCES.index(r["source"])))


def table(summary: dict) -> str:
    lines = [
        "| model | manuals | games | roles right | movements right | descriptions placed right |",
        "|---|---|---|---|---|---|",
    ]
    for model, by_source in summary.items():
        for source in [s for s in SOURCES if s in by_source]:
            c = by_source[source]
            ident = "-" if c["identity"] is None else f"{c['identity']:.0%}"
            lines.append(f"| {model} | {source} | {c['games']} | {c['roles']:.0%} | {c['movement']:.0%} | {ident} |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="dataset holding newall-test")
    ap.add_argument("--games", type=int, default=TABLE3_GAMES, help="games of Table 3's 30 (every k-th)")
    ap.add_argument("--models", nargs="+", default=["emma-lwm", "observational"],
                    help="shipped checkpoints (lwm_models/checkpoints/), or NAME=DIR")  # fmt: skip
    ap.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES, metavar="SOURCE")
    ap.add_argument("--samples", type=int, default=8, help="imagined probes per ordering of two entities")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument(
        "--out", type=Path, default=OUT, help="summary JSON (records beside it, .jsonl); other models' results are kept"
    )
    args = ap.parse_args()
    torch.set_num_threads(1)
    if problem := dataset_source_problem(args.data, SPLIT, args.sources):
        raise SystemExit(problem)
    ds = TrajectoryDataset(args.data, SPLIT)
    games = table3_games(len(ds.games), args.games)
    names = [spec.partition("=")[0] for spec in args.models]
    records_path = args.out.with_suffix(".jsonl")
    kept = [json.loads(line) for line in records_path.open()] if records_path.is_file() else []
    records = [r for r in kept if (r["model"], r["source"]) not in {(m, s) for m in names for s in args.sources}]
    began = time.perf_counter()
    for spec in args.models:
        name, _, path = spec.partition("=")
        model, _config = load_checkpoint(path or ROOT / "lwm_models" / "checkpoints" / name)
        encoder = model.frozen_text_encoder()
        for source in args.sources:
            for g in games:
                records.append({"model": name, **score(model, encoder, ds, g, source, args.seed, args.samples)})
            print(table({name: summarise(records)[name]}).splitlines()[-1], flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    summary = {
        "settings": {
            "split": SPLIT,
            "data": str(args.data),
            "games": games,
            "samples": args.samples,
            "seed": args.seed,
        },
        "results": summarise(records),
        "run": {
            "command": " ".join(["benchmarks/read_back.py", *sys.argv[1:]]),
            "commit": commit.strip(),
            "seconds": round(time.perf_counter() - began, 1),
        },  # fmt: skip
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    args.out.with_suffix(".jsonl").write_text("".join(json.dumps(r) + "\n" for r in in_order(records)))
    print(table(summary["results"]))
    print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

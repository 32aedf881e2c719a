"""Language robustness (issue 30): the shipped world models' NewAll test cross-entropy, and
imagined reward and termination precision, when only the wording of the manuals changes.

The episodes stay the same (the first `--episodes` of NewAll test, evenly spaced, as `lwm eval
--loss-episodes` picks them); only the three descriptions of each manual are re-drawn, for the same
triples, from one source:

- dataset: the descriptions the dataset was generated with (human-written, for data/human);
- generated: the project's own description generator;
- stress:STYLE: one style of the held-out part of the project's stress set, never tuned on.

Beside each source, the keyword parser's identity, movement and role accuracy on the same manual
slots, as GPTHard and the review page use it (keywords only) and with the frozen text encoder's
guess where no keyword rule decides; and in each model's cell ("reads N%") how often the world
model itself reads a description as about its true identity (lwm_models/world/reading.py).
Cross-entropy and imagination come from
`lwm_models.world.evaluate.evaluate_model`, the code of `lwm eval`, so the figures are `lwm eval`'s.
A model that reads no text (Observational) is evaluated once and its figures stand for every
source.

Runs can be split (e.g. one model per run, each under ten minutes): results are merged into the
`--out` file by (model, source), and the table printed is the merged one.

    flock /tmp/lwm-heavy.lock env OMP_NUM_THREADS=1 .venv/bin/python benchmarks/language_robustness.py \\
        --data data/human-newall-test --episodes 200 --imagination-episodes 100 --models emma-lwm
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from functools import lru_cache
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.data.dataset import dataset_source_problem  # noqa: E402
from lwm_models.messenger.constants import ALL_TRIPLES  # noqa: E402
from lwm_models.text.parser import parse_description  # noqa: E402
from lwm_models.text.stress import manual_sources, source_pools  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint  # noqa: E402
from lwm_models.world.evaluate import evaluate_model  # noqa: E402
from lwm_models.world.frozen_text import FrozenTextEncoder  # noqa: E402
from lwm_models.world.training_data import SplitTokens, redraw_manuals  # noqa: E402

SPLIT = "newall-test"
MODELS = ("emma-lwm", "gpthard", "observational")
SOURCES = manual_sources()
OUT = ROOT / "results" / "language-robustness" / "summary.json"


def split_with_manuals(data_dir: Path, source: str, encoder, router, seed: int) -> SplitTokens:
    """NewAll test with its manuals drawn from `source` (encoded for the model)."""
    pools = source_pools(source, seed)
    if pools is None:
        return SplitTokens(data_dir, SPLIT, encoder, router)
    data = SplitTokens(data_dir, SPLIT, None, router)
    redraw_manuals(data, pools, encoder, seed)
    return data


def parser_on_slots(data: SplitTokens, episodes: int | None, encoder=None) -> dict:
    """The keyword parser's accuracy on the manual slots of the evaluated episodes (with
    `encoder`: with its embedding-space guess where no keyword rule decides)."""
    n = np.zeros(3)
    slots = 0
    for e in data.evaluated_episodes(episodes):
        for k, code in enumerate(data.ds.parses[int(e)]):
            truth = ALL_TRIPLES[int(code)]
            parsed = parse_description(data.texts[int(data.manuals[e, k])], encoder)
            n += [parsed[0] == truth[0], parsed[1] == truth[1], parsed[2] == truth[2]]
            slots += 1
    return {"slots": slots, **{f: float(v / max(1, slots)) for f, v in zip(("identity", "movement", "role"), n)}}


@lru_cache(maxsize=1)
def text_encoder() -> FrozenTextEncoder:
    return FrozenTextEncoder()


def reading_on_slots(model, encoder, data: SplitTokens, episodes: int | None) -> float | None:
    """How often the world model reads a manual slot's description as about its true identity
    (lwm_models/world/reading.py); None for a model that reads no text."""
    from lwm_models.world.reading import read_identities

    slots = [(int(data.manuals[e, k]), ALL_TRIPLES[int(code)][0])
             for e in data.evaluated_episodes(episodes) for k, code in enumerate(data.ds.parses[int(e)])]  # fmt: skip
    texts = sorted({t for t, _ in slots})
    read = dict(zip(texts, read_identities(model, encoder, [data.texts[t] for t in texts])))
    if all(r is None for r in read.values()):
        return None
    return float(np.mean([read[t] == identity for t, identity in slots]))


def evaluate(model_spec: str, sources: list[str], args, summary: dict) -> None:
    model_name, _, path = model_spec.partition("=")
    model, config = load_checkpoint(path or ROOT / "lwm_models" / "checkpoints" / model_name)
    encoder = model.frozen_text_encoder()
    reads_text = encoder is not None or model.route is not None
    shared = None
    for source in sources:
        began = time.perf_counter()
        data = split_with_manuals(args.data, source, encoder, model.route, args.seed)
        summary["parser"][source] = parser_on_slots(data, args.episodes)
        summary.setdefault("parser_with_encoder", {})[source] = parser_on_slots(data, args.episodes, text_encoder())
        if reads_text or shared is None:
            results = evaluate_model(model, {SPLIT: data}, args.episodes, args.imagination_episodes, args.seed)
            shared = results[SPLIT]
        entry = {
            "cross_entropy": shared["cross_entropy"],
            "reads_text": reads_text,
            "identity_read": reading_on_slots(model, encoder, data, args.episodes),
            "seconds": round(time.perf_counter() - began, 1),
        }
        if "imagination" in shared:
            im = shared["imagination"]
            keys = ("reward_precision", "termination_precision", "reward_recall", "termination_recall", "episodes")
            entry["imagination"] = {k: im[k] for k in keys}
        summary["results"].setdefault(model_name, {})[source] = entry
        ce = entry["cross_entropy"]["total"]
        read = "" if entry["identity_read"] is None else f", identity read {entry['identity_read']:.1%}"
        print(f"{model_name:<14} {source:<22} CE {ce:.4f}{read}  ({entry['seconds']} s)", flush=True)
    summary["checkpoints"][model_name] = {"kind": config["kind"], "steps": config.get("steps"), "path": path or None}


def table(summary: dict) -> str:
    models = [m for m in MODELS if m in summary["results"]] + [m for m in summary["results"] if m not in MODELS]
    sources = [s for s in SOURCES if any(s in summary["results"][m] for m in models)]
    imagined = any("imagination" in r for m in models for r in summary["results"][m].values())
    head = " | ".join(models) + " | parser: identity / movement / role | with encoder guesses |"
    lines = ["| manuals of NewAll test | " + head, "|" + "---|" * (len(models) + 3)]
    for source in sources:
        cells = []
        for m in models:
            r = summary["results"][m].get(source)
            if r is None:
                cells.append("")
                continue
            cell = f"{r['cross_entropy']['total']:.3f}"
            if imagined and "imagination" in r:
                im = r["imagination"]
                cell += f" ({im['reward_precision']:.2f} / {im['termination_precision']:.2f})"
            if r.get("identity_read") is not None:
                cell += f", reads {r['identity_read']:.0%}"
            cells.append(cell)
        for key in ("parser", "parser_with_encoder"):
            p = summary.get(key, {}).get(source)
            cells.append(f"{p['identity']:.1%} / {p['movement']:.1%} / {p['role']:.1%}" if p else "")
        lines.append(f"| {source} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, required=True, help="dataset holding newall-test")
    ap.add_argument("--episodes", type=int, default=200, help="NewAll test episodes (evenly spaced; 0: all)")
    ap.add_argument(
        "--imagination-episodes", type=int, default=0, help="episodes to imagine for reward/termination precision"
    )
    ap.add_argument(
        "--models",
        nargs="+",
        default=list(MODELS),
        help="shipped checkpoints (lwm_models/checkpoints/), or NAME=DIR for any checkpoint directory",
    )
    ap.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES, metavar="SOURCE")
    ap.add_argument("--seed", type=int, default=0, help="seed of the re-drawn manuals and of the imagination")
    ap.add_argument("--out", type=Path, default=OUT, help="summary JSON; results already in it are kept and merged")
    args = ap.parse_args()
    if problem := dataset_source_problem(args.data, SPLIT, args.sources):
        raise SystemExit(problem)
    torch.set_num_threads(1)
    episodes = args.episodes or None
    settings = {
        "split": SPLIT,
        "data": str(args.data),
        "episodes": episodes,
        "imagination_episodes": args.imagination_episodes,
        "seed": args.seed,
    }
    summary = {"settings": settings, "results": {}, "parser": {}, "checkpoints": {}, "runs": []}
    if args.out.is_file():
        old = json.loads(args.out.read_text())
        if old.get("settings") != settings:
            raise SystemExit(f"{args.out} holds results measured with {old.get('settings')}, not {settings}")
        summary = old
    args.episodes = episodes
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    began = time.perf_counter()
    for name in args.models:
        evaluate(name, args.sources, args, summary)
    summary["runs"].append(
        {
            "command": " ".join(["benchmarks/language_robustness.py", *sys.argv[1:]]),
            "commit": commit.strip(),
            "seconds": round(time.perf_counter() - began, 1),
        }
    )
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    print()
    print(f"NewAll test, {episodes or 'all'} episodes: total cross-entropy (obs + reward + done)", end="")
    print(", imagined (reward / termination precision)" if args.imagination_episodes else "")
    print(table(summary))
    print(f"written to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

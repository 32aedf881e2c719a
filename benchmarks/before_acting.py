"""What a plan rests on: the manual's reading before any step (lwm_models/world/manual_reading.py).

A plan is imagined before the agent acts, so what it sees of a person's words is the reading alone.
For NewAll test games drawn at random, per reader (a shipped checkpoint, or `words`: the keyword
parser alone) and per manual source, this prints and writes:
- roles right: the reading's likeliest assignment of the roles is the game's (per game);
- movements right and descriptions placed right (per entity);
- stable: the reading is the same under all 6 orders of the descriptions (per game); there is no
  seed to vary, nothing is sampled;
- the calibration of the stated certainty: expected calibration error (10 bins) of each entity's
  role ("airplane the enemy (93%)"), of its movement, and of the whole assignment, with a
  reliability plot (PNG);
- questions: those asked before planning (`ManualReading.questions`), answered truthfully by the
  simulated person, and the roles right after the answers;
- unusable text: manuals whose descriptions carry no usable fact (gibberish, other games'
  entities) and the share of entities with every role below 50%;
- the world model under the reading (with --data, for models): on evenly spaced recorded episodes
  of NewAll test with their manuals drawn from each source, the imagined reward and termination
  precision of a lone trajectory replaying the real actions from the real start (Table 2's, raw
  sampling), and the cross-entropy of the real episode under the reading before any step (its
  configurations mixed by their probabilities, never updated by the episode: what a plan rests
  on) beside the teacher-forced one (the readings' mixture updated by the episode as it goes).

Sources: `dataset` (the human-written descriptions of NewAll test, with --texts), `generated`
(the project's generator), `fresh` (the fresh held-out part, lwm_models/text/stress_fresh.json:
each description one of its triple's three, in any of the seven styles; per style the entities
described in it), and `unusable` (its unusable part, three per manual).

    flock /tmp/lwm-heavy.lock .venv/bin/python benchmarks/before_acting.py --models emma-lwm-hedged words \\
        --texts PATH/text_train.json PATH/text_val.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.data.splits import load_split  # noqa: E402
from lwm_models.messenger.constants import DEFAULT_MAX_STEPS, IDENTITIES, ROLES  # noqa: E402
from lwm_models.text.pools import DescriptionPools  # noqa: E402
from lwm_models.text.stress import fresh_pools, load_fresh  # noqa: E402
from lwm_models.world.base import losses  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint  # noqa: E402
from lwm_models.world.evaluate import ImaginationScore  # noqa: E402
from lwm_models.world.frozen_text import FrozenTextEncoder  # noqa: E402
from lwm_models.world.imagine import imagine  # noqa: E402
from lwm_models.world.manual_reading import calibration_for, evidence_for, read_manual  # noqa: E402
from lwm_models.world.tokens import ID_SLOTS  # noqa: E402
from lwm_models.world.training_data import SplitTokens, redraw_manuals  # noqa: E402

SPLIT = "newall-test"
SOURCES = ("dataset", "generated", "fresh", "unusable")
OUT = ROOT / "results" / "before-acting" / "summary.json"
BINS = 10


def ece(conf: list[float], right: list[bool], bins: int = BINS) -> float:
    """Expected calibration error: the bins' |accuracy - mean confidence|, weighted by their size."""
    conf_a, right_a = np.asarray(conf), np.asarray(right, dtype=float)
    edges = np.minimum((conf_a * bins).astype(int), bins - 1)
    return float(sum(abs(right_a[edges == b].mean() - conf_a[edges == b].mean()) * (edges == b).mean()
                     for b in range(bins) if (edges == b).any()))  # fmt: skip


def reliability(conf: list[float], right: list[bool], bins: int = BINS) -> list[dict]:
    conf_a, right_a = np.asarray(conf), np.asarray(right, dtype=float)
    edges = np.minimum((conf_a * bins).astype(int), bins - 1)
    out = []
    for b in range(bins):
        at = edges == b
        if at.any():
            out.append({"bin": b / bins, "n": int(at.sum()), "confidence": round(float(conf_a[at].mean()), 4),
                        "accuracy": round(float(right_a[at].mean()), 4)})  # fmt: skip
    return out


class Reader:
    """A reader as the system uses it: a checkpoint's prototypes and calibration, or the words."""

    def __init__(self, name: str):
        self.name = name
        if name == "words":
            self.model, self.encoder, self.calibration = None, FrozenTextEncoder(), calibration_for(None)
        else:
            folder = Path(name) if Path(name).is_dir() else ROOT / "lwm_models" / "checkpoints" / name
            self.model, _ = load_checkpoint(folder)
            self.model.eval()
            self.encoder = self.model.frozen_text_encoder()
            self.calibration = calibration_for(folder)
        self._cache: dict[str, object] = {}

    def evidence(self, texts: list[str]) -> list:
        todo = [t for t in dict.fromkeys(texts) if t not in self._cache]
        if todo:
            self._cache.update(zip(todo, evidence_for(self.model, self.encoder, todo, self.calibration.sentence),
                                   strict=True))  # fmt: skip
        return [self._cache[t] for t in texts]

    def read(self, texts: list[str], board: list[int], facts=()):
        return read_manual(self.evidence(texts), board, self.calibration, facts)


def truth_of(triples) -> tuple[tuple[int, ...], dict[int, tuple]]:
    holder = {r: IDENTITIES[i] for i, _, r in triples}
    return tuple(holder[r] for r in ROLES), {IDENTITIES[i]: (i, m, r) for i, m, r in triples}


def score(reader: Reader, texts: list[str], triples: list[tuple], styles: list[str]) -> dict:
    board = [IDENTITIES[t[0]] for t in triples]
    assignment, by_id = truth_of(triples)
    reading = reader.read(texts, board)
    options, p = reading.assignments()
    best = reading.best()
    entities = []
    for j, (ident, mv, role) in enumerate(triples):
        e = IDENTITIES[ident]
        about = reading.about(e)
        entities.append({
            "identity": ident, "style": styles[j],
            "role_p": round(best[e]["p"], 4), "role_right": best[e]["role"] == role,
            "movement_p": round(best[e]["movement_p"], 4), "movement_right": best[e]["movement"] == mv,
            "placed_right": int(np.argmax(about)) == j, "max_role_p": round(float(reading.role_p(e).max()), 4),
        })  # fmt: skip
    top = int(np.argmax(np.round(p, 9)))
    stable = all(
        _same(reading, reader.read([texts[k] for k in order], board)) for order in itertools.permutations(range(3))
    )
    # The simulated person answers the questions asked, each with the truth.
    facts, asked = [], 0
    answered = reading
    for _ in range(3):
        questions = answered.questions()
        if not questions:
            break
        q = questions[0]
        facts.append(
            {"entity": q.entity, "field": q.field, "value": by_id[IDENTITIES[q.entity]][2 if q.field == "role" else 1]}
        )
        asked += 1
        answered = reader.read(texts, board, facts)
    after = answered.assignments()
    return {
        "roles_right": options[top] == assignment, "roles_p": round(float(p[top]), 4), "stable": stable,
        "entities": entities, "questions": asked,
        "roles_right_answered": after[0][int(np.argmax(np.round(after[1], 9)))] == assignment,
        "movements_right_answered": sum(answered.best()[IDENTITIES[t[0]]]["movement"] == t[1] for t in triples),
    }  # fmt: skip


def _same(a, b) -> bool:
    ja, jb = a.to_json(), b.to_json()
    keys = ("identity", "role", "p", "movement", "movement_p", "roles", "movements")
    return all(all(x[k] == y[k] for k in keys) for x, y in zip(ja, jb, strict=True))


def manuals(source: str, games, rng, texts_files) -> list[tuple[list[str], list[tuple], list[str]]]:
    """Per game: the manual's descriptions, their triples and their styles."""
    out = []
    if source == "fresh":
        by_triple: dict[tuple, list] = {}
        for e in load_fresh():
            by_triple.setdefault(e.triple, []).append(e)
    elif source == "unusable":
        junk = [u["text"] for u in load_fresh(unusable=True) if u["kind"] in ("gibberish", "other-game")]
    else:
        pools = (
            DescriptionPools.generated(seed=0) if source == "generated" else DescriptionPools.from_files(texts_files)
        )
    for game in games:
        triples = [(e.identity, e.movement, e.role) for e in game.entities]
        if source == "fresh":
            picked = [by_triple[t][int(rng.integers(len(by_triple[t])))] for t in triples]
            out.append(([e.text for e in picked], triples, [e.style for e in picked]))
        elif source == "unusable":
            out.append(([junk[int(i)] for i in rng.choice(len(junk), 3, replace=False)], triples, ["unusable"] * 3))
        else:
            out.append((pools.draw(SPLIT, triples, rng), triples, [source] * 3))
    return out


def _add_cross_entropy(sums: dict, out) -> None:
    """Per kind (obs, reward, done): add an episode's summed cross-entropy and its token count
    (`losses`' sums and counts)."""
    for kind in out.sums:
        nll, n = sums.get(kind, (0.0, 0))
        sums[kind] = (nll + float(out.sums[kind]), n + int(out.counts[kind]))


def _total(sums: dict) -> float:
    """As `lwm eval` reports it: the per-token means of obs, reward and done, summed."""
    return sum(nll / max(1, n) for nll, n in sums.values())


@torch.no_grad()
def world_model_figures(reader: Reader, source: str, data_root: Path, episodes: int, seed: int) -> dict:
    """The world model under the manual's reading, on recorded episodes (module docstring)."""
    model, encoder = reader.model, reader.encoder
    data = SplitTokens(data_root, SPLIT, encoder, model.route)
    if source != "dataset":
        pools = fresh_pools() if source == "fresh" else DescriptionPools.generated(seed=0)
        redraw_manuals(data, pools, encoder, seed=seed)
    score = ImaginationScore()
    prior: dict = {}
    forced: dict = {}
    for e in data.evaluated_episodes(episodes):
        ep = data.ds[int(e)]
        tokens, lengths = data.segments(np.array([e]), np.zeros(1, dtype=np.int64))
        texts = [data.texts[int(i)] for i in data.manuals[e]]
        manual = model.on_board(model.read_manual(texts, encoder), tokens[:, torch.as_tensor(ID_SLOTS)])
        _add_cross_entropy(prior, losses(model.prior_predictions(tokens, lengths, manual)))
        _add_cross_entropy(forced, model(tokens, lengths, data.manual_batch(np.array([e]))))
        actions = np.zeros((1, DEFAULT_MAX_STEPS), dtype=np.int64)
        actions[0, : len(ep.actions) - 1] = ep.actions[1:]
        score.add(imagine(model, manual, ep.observations[0][None], 1, actions, seed=seed + int(e)), [ep])
    m = score.metrics()
    return {"episodes": int(m.episodes), "reward_precision": m.reward_precision,
            "termination_precision": m.termination_precision, "prior_cross_entropy": _total(prior),
            "teacher_forced_cross_entropy": _total(forced)}  # fmt: skip


def summarise(records: list[dict]) -> dict:
    out: dict = {}
    for r in records:
        out.setdefault(r["reader"], {}).setdefault(r["source"], []).append(r)
    summary: dict = {}
    for reader, by_source in out.items():
        for source, recs in by_source.items():
            ents = [e for r in recs for e in r["entities"]]
            cell = {
                "games": len(recs),
                "roles_right": np.mean([r["roles_right"] for r in recs]),
                "movements_right": np.mean([e["movement_right"] for e in ents]),
                "placed_right": np.mean([e["placed_right"] for e in ents]),
                "stable": np.mean([r["stable"] for r in recs]),
                "ece_role": ece([e["role_p"] for e in ents], [e["role_right"] for e in ents]),
                "ece_movement": ece([e["movement_p"] for e in ents], [e["movement_right"] for e in ents]),
                "ece_assignment": ece([r["roles_p"] for r in recs], [r["roles_right"] for r in recs]),
                "mean_role_p": np.mean([e["role_p"] for e in ents]),
                "questions": np.mean([r["questions"] for r in recs]),
                "roles_right_answered": np.mean([r["roles_right_answered"] for r in recs]),
                "all_roles_below_half": np.mean([e["max_role_p"] < 0.5 for e in ents]),
                "reliability_role": reliability([e["role_p"] for e in ents], [e["role_right"] for e in ents]),
            }
            styles = sorted({e["style"] for e in ents})
            if len(styles) > 1:
                cell["by_style"] = {
                    s: {"entities": len(se), "role_right": np.mean([e["role_right"] for e in se]),
                        "movement_right": np.mean([e["movement_right"] for e in se]),
                        "ece_role": ece([e["role_p"] for e in se], [e["role_right"] for e in se])}
                    for s in styles if (se := [e for e in ents if e["style"] == s])
                }  # fmt: skip
            summary.setdefault(reader, {})[source] = _rounded(cell)
    return summary


def _rounded(x):
    if isinstance(x, dict):
        return {k: _rounded(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_rounded(v) for v in x]
    if isinstance(x, (float, np.floating)):
        return round(float(x), 4)
    return x


def table(summary: dict) -> str:
    lines = ["| reader | manuals | games | roles right | movements right | placed right | stable | ECE role / movement "
             "/ assignment | questions a manual | roles right, questions answered | every role < 50% |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for reader, by_source in summary.items():
        for source, c in by_source.items():
            lines.append(
                f"| {reader} | {source} | {c['games']} | {c['roles_right']:.0%} | {c['movements_right']:.0%} | "
                f"{c['placed_right']:.0%} | {c['stable']:.0%} | {c['ece_role']:.3f} / {c['ece_movement']:.3f} / "
                f"{c['ece_assignment']:.3f} | {c['questions']:.2f} | {c['roles_right_answered']:.0%} | "
                f"{c['all_roles_below_half']:.0%} |"
            )
    return "\n".join(lines)


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 5))
    ax.plot([0, 1], [0, 1], color="grey", lw=1, ls="--", label="perfect calibration")
    for reader, by_source in summary.items():
        for source, c in by_source.items():
            if source == "unusable":
                continue
            pts = c["reliability_role"]
            ax.plot([b["confidence"] for b in pts], [b["accuracy"] for b in pts], marker="o", ms=3,
                    label=f"{reader}, {source} (ECE {c['ece_role']:.3f})")  # fmt: skip
    ax.set_xlabel("stated certainty of an entity's role")
    ax.set_ylabel("how often it was right")
    ax.set_title("The reading before acting: reliability (NewAll test)")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--models", nargs="+", default=["emma-lwm-hedged", "words"],
        help="readers: shipped checkpoints (or folders), and `words` for the keyword parser alone",
    )  # fmt: skip
    ap.add_argument("--sources", nargs="+", default=list(SOURCES), choices=SOURCES)
    ap.add_argument(
        "--texts", type=Path, nargs="*", default=[], help="the dataset's description files (source dataset)"
    )
    ap.add_argument("--games", type=int, default=200, help="NewAll test games, drawn at random")
    ap.add_argument("--seed", type=int, default=0, help="draws the games and their manuals")
    ap.add_argument("--out", type=Path, default=OUT, help="summary JSON; records beside it (.jsonl), plot (.png)")
    ap.add_argument("--data", type=Path, default=None,
                    help="a dataset with NewAll test's recorded episodes (lwm data generate): the world model "
                         "under the reading is measured on them")  # fmt: skip
    ap.add_argument("--episodes", type=int, default=100, help="recorded episodes, evenly spaced (with --data)")
    args = ap.parse_args()
    torch.set_num_threads(2)
    sources = [s for s in args.sources if s != "dataset" or args.texts]
    if len(sources) < len(args.sources):
        print("before_acting: no --texts, so no `dataset` source", file=sys.stderr)
    split = load_split(SPLIT)
    rng = np.random.default_rng(args.seed)
    games = [split[int(i)] for i in rng.choice(len(split), size=min(args.games, len(split)), replace=False)]
    began = time.perf_counter()
    records, world = [], {}
    for name in args.models:
        reader = Reader(name)
        for source in sources:
            drawn = manuals(source, games, np.random.default_rng([args.seed, SOURCES.index(source)]), args.texts)
            for (texts, triples, styles), game in zip(drawn, games, strict=True):
                records.append({"reader": name, "source": source, "game": game.entities[0].identity,
                                **score(reader, texts, triples, styles)})  # fmt: skip
            print(table({name: {source: summarise(records)[name][source]}}).splitlines()[-1], flush=True)
            if args.data is not None and reader.model is not None and source != "unusable":
                figures = world_model_figures(reader, source, args.data, args.episodes, args.seed)
                world.setdefault(name, {})[source] = _rounded(figures)
                print(f"  world model under the reading, {source}: {world[name][source]}", flush=True)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout
    summary = {
        "settings": {"split": SPLIT, "games": len(games), "seed": args.seed, "readers": args.models,
                     "sources": sources, "recorded episodes": args.episodes if args.data else 0},
        "results": summarise(records),
        "world_model": world,
        "run": {"command": " ".join(["benchmarks/before_acting.py", *sys.argv[1:]]), "commit": commit.strip(),
                "seconds": round(time.perf_counter() - began, 1)},
    }  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(summary, indent=2) + "\n")
    args.out.with_suffix(".jsonl").write_text("".join(json.dumps(_rounded(r)) + "\n" for r in records))
    plot(summary["results"], args.out.with_suffix(".png"))
    print(table(summary["results"]))
    print(f"written to {args.out} (and .jsonl, .png)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Fit a model's reading calibration (lwm_models/world/manual_reading.py) and write it beside the
checkpoint as reading.json, with the anchors imagination conditions each believed triple on
(reading_anchors.safetensors); with --words-only, the calibration of the keyword parser alone
(lwm_models/text/words_reading.json), which models without prototypes use.

What it is fitted on, never on what a report is made on:
- descriptions: the stress set's tune, dev, written, first held-out and varied parts (the fresh
  part is the held-out one now), 24 of the generator's descriptions
  per triple, (with --texts) the dataset's human-written descriptions of the training and dev
  splits, and stray text, which is about no entity on any board: generated descriptions with the
  entity's name swapped for a thing that is in no Messenger game, strings of random letters, and
  small talk (`OFF_TOPIC`). Its things and topics were chosen apart from those of the fresh part's
  unusable descriptions, so that the report on those stays a report on text never fitted on;
- manuals (the two temperatures): 300 games of the three dev splits, each read with descriptions
  drawn from the stress set's hand-written part, the text most like a person's own.

    flock /tmp/lwm-heavy.lock .venv/bin/python scripts/fit_reading.py --model emma-lwm-hedged \\
        --texts PATH/text_train.json PATH/text_val.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import re
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lwm_models.data.splits import load_split  # noqa: E402
from lwm_models.messenger.constants import ALL_TRIPLES, IDENTITIES, MOVEMENTS, ROLES  # noqa: E402
from lwm_models.text.generator import generate_descriptions  # noqa: E402
from lwm_models.text.parser import IDENTITY_KEYWORDS  # noqa: E402
from lwm_models.text.pools import DescriptionPools  # noqa: E402
from lwm_models.text.stress import load_stress, load_varied  # noqa: E402
from lwm_models.world.checkpoint import load_checkpoint  # noqa: E402
from lwm_models.world.frozen_text import FrozenTextEncoder  # noqa: E402
from lwm_models.world.manual_reading import (  # noqa: E402
    ANCHORS_FILE,
    CALIBRATION_FILE,
    VALUES,
    Calibration,
    evidence_for,
    fit_anchors,
    fit_fact_weights,
    fit_identity_rates,
    read_manual,
    save_anchors,
)
from lwm_models.world.sentence_reader import SentenceReader, SentenceReaderConfig, fit_sentence_reader  # noqa: E402

STRESS_PARTS = ("tune", "dev", "written", "heldout")  # the fresh part is held out in their place
DEV_SPLITS = ("newcombo-dev", "newattr-dev", "newall-dev")
GENERATED_PER_TRIPLE = 24
# Things in no Messenger game and near none of its entities (no aircraft, boat, weapon, bird, fish,
# royal, magician or machine person), none of them in the fresh part's unusable descriptions.
STRAY_NOUNS = (
    "lamp", "teapot", "kettle", "umbrella", "clock", "candle", "cupcake", "mushroom", "pumpkin", "barrel",
    "anvil", "lantern", "statue", "fountain", "tent", "bucket", "broom", "banana", "pineapple", "snail",
    "goat", "cow", "sheep", "camel", "kangaroo", "donkey", "rhino", "frog", "beetle", "windmill",
    "scarecrow", "violin", "piano", "giraffe", "sofa", "teddy bear", "troll", "goblin", "ogre", "werewolf",
    "mermaid", "centaur", "yeti", "gnome", "mummy", "skeleton", "cyclops", "minotaur", "bus", "truck",
    "bicycle", "tram", "tractor", "boulder", "puddle", "campfire", "bomb", "spider", "snake", "bear",
    "lion", "tiger", "monkey", "pig", "horse", "rabbit", "squirrel", "hedgehog", "crocodile", "cookie",
    "pizza", "apple", "carrot", "chair", "table", "ladder", "mailbox", "robe", "hat", "bell",
    "mirror", "vase", "drum", "trumpet", "bridge", "castle", "well", "cloud", "comet", "crystal",
)  # fmt: skip
# Small talk about nothing on a board: openings and endings joined at random, and sentences whole.
OFF_TOPIC_OPENINGS = (
    "the match last sunday", "my sister's new job", "the quarterly report", "this old laptop", "the jazz concert",
    "our garden", "the history exam", "the hotel we booked", "the spreadsheet", "the new phone update",
    "grandpa's stories about the war", "that documentary", "the board meeting", "my running shoes",
    "the museum downtown", "the rent", "the guitar lessons", "the movie everyone talks about", "my email inbox",
    "the stock market", "the camping trip", "the math homework", "the printer on the third floor",
    "the wedding in june", "his podcast", "the election", "our neighbour's renovation", "the chess club",
    "the parking situation", "the yoga class", "the new tax form", "the train strike", "my cousin's band",
)  # fmt: skip
OFF_TOPIC_MIDDLES = (
    "went on for far too long", "was better than I expected", "needs to be finished by tuesday",
    "keeps crashing whenever I open it", "reminded me of when I was young", "costs more every single year",
    "is honestly overrated", "made everyone laugh", "has to be rescheduled again", "was sold out by noon",
    "is something I should really fix", "got five stars from the critics", "was mostly about taxes",
    "starts at half past seven", "is the only thing anyone talks about", "took three hours and a lot of coffee",
    "will probably be cancelled", "was on the news this morning", "is stuck in my head",
)  # fmt: skip
OFF_TOPIC_WHOLE = (
    "Did anyone record the game last night?", "Please water the plants while I'm away.",
    "The meeting has moved to room 4B.", "I can't find my keys anywhere.", "Happy birthday, hope it's a great one!",
    "Remember to back up your files before the update.", "The invoice is attached, let me know if it's wrong.",
    "We should repaint the hallway this spring.", "Who left the window open?", "This song is so catchy.",
    "Sorry, wrong chat.", "ok", "thanks!", "test test one two three", "hello is anyone there",
    "I'll be five minutes late.", "The password needs a number and a symbol.", "Press any key to continue.",
    "Chapter one: it was a quiet town.", "Add two cups of flour and stir.", "The package was delivered.",
    "The score was three to one at half time.", "Interest rates went up again.", "No comment.",
    "Can you send me the slides?", "It's all fine, don't worry about it.",
)  # fmt: skip

ANCHORED_ON = "the dataset's training and dev text where it has the triple, else the generator's"
STRAY_WEIGHT = 0.1  # of a source's weight: a person's text is seldom about no entity of the game
# The sentence reader sees stray text more often than that, so that it learns what is no entity of
# the game; the rates and weights fitted on its readings still weigh stray text at STRAY_WEIGHT.
STRAY_SAMPLED = 0.5
TEMPERATURES = np.round(np.arange(0.2, 4.01, 0.05), 2)


def fitting_texts(texts: list[Path], seed: int) -> dict[str, dict[tuple, list[str]]]:
    """Descriptions of known truth to fit on, by source and triple."""
    sources: dict[str, dict[tuple, list[str]]] = {"stress": {}, "varied": {}, "generator": {}, "dataset": {}}
    for part in STRESS_PARTS:
        for e in load_stress(part):
            sources["stress"].setdefault(e.triple, []).append(e.text)
    for e in load_varied():
        sources["varied"].setdefault(e.triple, []).append(e.text)
    rng = np.random.default_rng(seed)
    for t in ALL_TRIPLES:
        found = generate_descriptions(t)
        picks = rng.choice(len(found), size=min(GENERATED_PER_TRIPLE, len(found)), replace=False)
        sources["generator"][t] = [found[i] for i in sorted(picks)]
    if texts:
        pools = DescriptionPools.from_files(texts, seed=seed)
        for split in ("train", *DEV_SPLITS):
            for t, found in pools.pools[split].items():
                if (split, t) not in pools.fallbacks:
                    sources["dataset"].setdefault(t, []).extend(found)
    # Stray text is about no board entity: its identity is never a board's, its movement and role
    # (where it has any) are the swapped description's, and random letters state nothing.
    stray: dict[tuple, list[str]] = {}
    for t in ALL_TRIPLES:
        for text in sources["generator"][t][:6]:
            names = sorted(IDENTITY_KEYWORDS[t[0]], key=len, reverse=True)
            noun = STRAY_NOUNS[int(rng.integers(len(STRAY_NOUNS)))]
            swapped = re.sub(r"\b(" + "|".join(map(re.escape, names)) + r")\b", noun, text, flags=re.I)
            if swapped != text:
                stray.setdefault(("?", t[1], t[2]), []).append(swapped)
    letters = list("abcdefghijklmnopqrstuvwxyz")
    for _ in range(150):
        words = ["".join(rng.choice(letters, size=int(rng.integers(2, 9)))) for _ in range(int(rng.integers(2, 9)))]
        stray.setdefault(("?", "?", "?"), []).append(" ".join(words))
    for _ in range(150):
        opening = OFF_TOPIC_OPENINGS[int(rng.integers(len(OFF_TOPIC_OPENINGS)))]
        middle = OFF_TOPIC_MIDDLES[int(rng.integers(len(OFF_TOPIC_MIDDLES)))]
        stray[("?", "?", "?")].append(f"{opening} {middle}.".capitalize())
    stray[("?", "?", "?")] += list(OFF_TOPIC_WHOLE)
    sources["stray"] = stray
    return {s: {t: list(dict.fromkeys(v)) for t, v in by.items()} for s, by in sources.items() if by}


def cached_sentence_reader(work: Path, texts, truth_of, known_of, weights, folds, cfg, seed: int):
    """The sentence reader and its held-out readings: trained (about 20 minutes on two cores), or
    taken from `work` where a run on the same text, seed and settings left them."""
    key = hashlib.sha256(json.dumps([texts, [truth_of[n].tolist() for n in truth_of], weights.round(8).tolist(),
                                     str(cfg), seed]).encode()).hexdigest()[:16]  # fmt: skip
    work.mkdir(parents=True, exist_ok=True)
    reader_file, held_file = work / f"sentence-{key}.safetensors", work / f"held-out-{key}.npz"
    if reader_file.is_file() and held_file.is_file():
        print(f"sentence reader from {reader_file}", flush=True)
        found = np.load(held_file)
        return SentenceReader.load(reader_file), {name: found[name] for name in truth_of}
    reader, held_out = fit_sentence_reader(texts, truth_of, known_of, weights, folds, cfg, seed,
                                           progress=lambda m: print(m, flush=True))  # fmt: skip
    reader.save(reader_file)
    np.savez(held_file, **held_out)
    return reader, held_out


def game_nll(readings_by_tau, truths) -> float:
    total = 0.0
    for reading, (assignment, movements) in zip(readings_by_tau, truths, strict=True):
        options, p = reading.assignments()
        total -= math.log(max(p[options.index(assignment)], 1e-12))
        for e, mv in movements.items():
            total -= math.log(max(reading.movement_p(e)[MOVEMENTS.index(mv)], 1e-12))
    return total


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--model", default="emma-lwm-hedged", help="a shipped checkpoint's name, or a checkpoint folder")
    ap.add_argument(
        "--words-only", action="store_true", help="fit the keyword parser's own calibration instead (no model, no head)"
    )
    ap.add_argument("--texts", type=Path, nargs="*", default=[], help="the dataset's human-written description files")
    ap.add_argument("--games", type=int, default=300, help="dev games whose manuals fit the temperatures")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--sentence-steps", type=int, default=SentenceReaderConfig.steps,
                    help="training steps of each fold of the sentence reader")  # fmt: skip
    ap.add_argument("--work", type=Path, default=Path.home() / ".cache" / "lwm" / "fit-reading",
                    help="where the trained sentence reader is kept, outside the repository, so a rerun on "
                         "the same text skips its training")  # fmt: skip
    args = ap.parse_args()
    torch.set_num_threads(2)
    folder = Path(args.model) if Path(args.model).is_dir() else ROOT / "lwm_models" / "checkpoints" / args.model
    model = None
    if args.words_only:
        encoder = FrozenTextEncoder()
        out = ROOT / "lwm_models" / "text" / "words_reading.json"
    else:
        model, _ = load_checkpoint(folder)
        model.eval()
        encoder = model.frozen_text_encoder()
        out = folder / CALIBRATION_FILE
    sources = fitting_texts(args.texts, args.seed)
    # Each source weighs the same: the dataset's plain text, far the most, would otherwise set the
    # rates that free-form words are read with.
    texts, truth, weights = [], [], []
    for by_triple in sources.values():
        n = sum(len(v) for v in by_triple.values())
        for t, found in by_triple.items():
            texts += found
            truth += [t] * len(found)
            weights += [1.0 / n] * len(found)
    per_source = np.asarray(weights) * len(texts) / len(sources)
    stray = np.array([t[0] == "?" for t in truth])
    sampled = np.where(stray, STRAY_SAMPLED, 1.0) * per_source
    weights = (np.where(stray, STRAY_WEIGHT, 1.0) * per_source).tolist()
    print(f"fitting on {len(texts)} descriptions: " + ", ".join(
        f"{s} {sum(len(v) for v in b.values())}" for s, b in sources.items()), flush=True)  # fmt: skip
    weights_a = np.asarray(weights)
    truth_of, known_of = {}, {}
    for k, name in ((1, "movement"), (2, "role")):
        values = VALUES[name]
        known_of[name] = np.array([t[k] in values for t in truth])
        truth_of[name] = np.array([values.index(t[k]) if t[k] in values else 0 for t in truth])
    # The subject: an entity of the game; a thing of no game (stray text with facts); nothing at all.
    known_of["subject"] = np.ones(len(truth), dtype=bool)
    truth_of["subject"] = np.array([0 if t[0] != "?" else 1 if t[2] != "?" else 2 for t in truth])
    # The stacking weights are fitted on the sentence reader's readings by adapters that never saw
    # the description (cross-fitting), so they weigh it as it reads new text.
    sentence, held_out = None, {name: np.zeros((len(texts), 3)) for name in truth_of}
    if not args.words_only:  # the keyword parser alone has no sentence reader
        cfg = SentenceReaderConfig(steps=args.sentence_steps)
        folds = np.random.default_rng(args.seed).integers(cfg.folds, size=len(texts))
        fitted = (texts, truth_of, known_of, sampled, folds, cfg, args.seed)
        sentence, held_out = cached_sentence_reader(args.work, *fitted)
    plain = evidence_for(model, encoder, texts)
    evidence = [replace(ev, sentence={n: tuple(held_out[n][i]) for n in held_out}) for i, ev in enumerate(plain)]
    calibration = Calibration(fit_identity_rates(evidence, [t[0] for t in truth], weights), {}, sentence)
    for name in ("movement", "role"):
        y, known = truth_of[name], known_of[name]
        features = np.stack([ev.features(name) for ev in evidence])
        calibration.weights[name] = fit_fact_weights(features[known], y[known], weights_a[known])
    index = {x: i for i, x in enumerate(texts)}

    # The temperatures: on whole manuals of the text most like a person's own, the stress set's
    # hand-written part (the rest was written from templates and phrase banks).
    written: dict[tuple, list[str]] = {}
    for e in load_stress("written"):
        written.setdefault(e.triple, []).append(e.text)
    rng = np.random.default_rng(args.seed)
    games = [g for s in DEV_SPLITS for g in load_split(s)]
    games = [games[i] for i in rng.choice(len(games), size=min(args.games, len(games)), replace=False)]
    manuals, truths = [], []
    for game in games:
        triples = [(e.identity, e.movement, e.role) for e in game.entities]
        drawn = [written[t][int(rng.integers(len(written[t])))] for t in triples]
        manuals.append(([evidence[index[x]] for x in drawn], [IDENTITIES[t[0]] for t in triples]))
        holder = {t[2]: IDENTITIES[t[0]] for t in triples}
        truths.append((tuple(holder[r] for r in ROLES), {IDENTITIES[t[0]]: t[1] for t in triples}))

    def nll(tau: float, tau_m: float) -> float:
        c = replace(calibration, temperature=tau, movement_temperature=tau_m)
        return game_nll([read_manual(ev, board, c) for ev, board in manuals], truths)

    calibration.temperature = float(min(TEMPERATURES, key=lambda t: nll(t, 1.0)))
    calibration.movement_temperature = float(min(TEMPERATURES, key=lambda t: nll(calibration.temperature, t)))
    calibration.fitted_on = {
        "descriptions": len(texts),
        "sources": {s: sum(len(v) for v in b.values()) for s, b in sources.items()},
        "stress parts": [*STRESS_PARTS, "varied"],
        **(
            {}
            if sentence is None
            else {
                "sentence reader": {
                    "steps per fold": sentence.cfg.steps,
                    "folds": sentence.cfg.folds,
                    "rank": sentence.cfg.rank,
                }
            }
        ),
        "generator": f"{GENERATED_PER_TRIPLE} per triple",
        "dataset": [p.name for p in args.texts] and ["train", *DEV_SPLITS],
        "stray weight": STRAY_WEIGHT,
        "stray sampled by the sentence reader": STRAY_SAMPLED,
        # The words alone have no world model to anchor.
        **({} if model is None else {"anchors": ANCHORED_ON if args.texts else "the generator's text"}),
        "temperature manuals": f"{len(games)} games of {', '.join(DEV_SPLITS)}, the stress set's written part",
        "model": "the keyword parser alone" if model is None else folder.name,
        "seed": args.seed,
        "command": " ".join(["scripts/fit_reading.py", *sys.argv[1:]]),
    }
    calibration.save(out)
    if model is not None:
        # The anchors: the dataset's training and dev text where it has the triple, else the generator's.
        trained = {t: sources.get("dataset", {}).get(t) or sources["generator"][t] for t in ALL_TRIPLES}
        save_anchors(folder / ANCHORS_FILE, *fit_anchors(model, encoder, trained))
        dataset_triples = sum(1 for t in ALL_TRIPLES if sources.get("dataset", {}).get(t))
        print(
            f"anchors: {dataset_triples} triples from the dataset's text, {108 - dataset_triples} from the generator's"
        )
    print(f"temperature {calibration.temperature}, movement {calibration.movement_temperature}")
    for cls, r in sorted(calibration.identity.items()):
        print(f"  identity {cls:18s} {r}")
    for name, w in calibration.weights.items():
        print(f"  {name:8s} words {w[0]:.2f}, model {w[1]:.2f}, sentence {w[2]:.2f}, bias {w[3:]}")
    print(f"written to {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

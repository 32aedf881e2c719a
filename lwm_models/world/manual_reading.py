"""The manual's reading: what each entity on the board is, from the words alone, before any step.

A plan is imagined before the agent makes a move, so it rests on what the manual says and nothing
else. This module turns a manual and its board into one reading: for each board entity, how
probable each movement and each role is, and which description is about it. Everything a person
sees before the agent acts (the read-back, the roles the agent acts on, the plan imagined under
them) comes from this one reading (docs/reading.md).

How a description is read. Three readers give evidence:
- the words: the offline keyword parser (`text/parser.py`): the entity its name keywords name (or,
  when none does, the frozen encoder's nearest name: "guessed"), and the movement and the role its
  cue words state, or nothing;
- the world model's own reading (hedged models): the triple whose prototype lies nearest to what
  its description attention reads (`hedged_reading.prototype_distances`);
- the sentence: the text encoder tuned to read a description's movement and role
  (`sentence_reader.py`), which reads word order and negation.
The movement and the role of a description are a softmax over their three values of a weighted
sum: the words' value, the model's value (each a one-hot) and the sentence reader's log-probabilities,
plus a bias per value: six numbers per fact, fitted on descriptions of known truth by
log-likelihood, so that a description's probabilities are calibrated where its text resembles the
fitting text. Identity is read from the words and the model: how the two agree puts it in a class
("a keyword names it and the model agrees", "only the encoder's nearest name", ...), each with the
measured rate of its first and second candidate being the truth, the rest spread evenly. Everything
is fitted once per model (`scripts/fit_reading.py`) on text that no report is made on: the stress
set's tune, dev, written and first held-out parts, its varied part, the generator's text, the
dataset's training text, and stray text about no entity of the game.

How a manual is read. A manual describes the three board entities, each once, and gives each role
to exactly one of them. The reading is exact over the 6 ways the descriptions map onto the board
entities and the 6 ways the roles are given, each weighed by the product of its descriptions'
probabilities raised to a temperature (fitted on whole manuals of hand-written text, so that the
stated probabilities match how often they come true). Movements ride on the mapping, with a
temperature of their own. The same words give the same reading whatever their order and whatever
the seed: nothing here is sampled. A world model imagines under the reading by conditioning each
description on its believed triple's anchor (`fit_anchors`, `HedgedReading._configured`).

Facts a person states (an answer to a question, `Question`) hold for sure: the reading keeps only
what agrees with them, so one answer can settle the other entities' roles too.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import LwmError
from ..messenger.constants import ID_TO_IDENTITY, IDENTITIES, MOVEMENTS, ROLES, Triple
from .sentence_reader import SENTENCE_FILE, SUBJECTS, SentenceReader

FIELDS = ("identity", "movement", "role")
VALUES: dict[str, tuple[str, ...]] = {"identity": tuple(IDENTITIES), "movement": MOVEMENTS, "role": ROLES}
CALIBRATION_FILE = "reading.json"  # beside a checkpoint's weights
ANCHORS_FILE = "reading_anchors.safetensors"  # and what imagination conditions each triple on
ASK_BELOW = 0.9  # a fact the reading is less sure of than this is asked about before planning
MAX_QUESTIONS = 3  # questions a manual asks at most before its plan
MOVEMENT_WORDS = {"chaser": "comes toward you", "fleeing": "moves away from you", "immovable": "stays where it is"}
ASKED_MOVEMENT = {"chaser": "come toward you", "fleeing": "move away from you", "immovable": "stay where it is"}
ROLE_WORDS = {"enemy": "the enemy", "message": "the message", "goal": "the goal"}


@dataclass(frozen=True)
class Evidence:
    """What the readers say of one description (module docstring); None: says nothing."""

    named: str | None  # the identity a keyword names
    guessed: str | None  # the encoder's nearest name, where no keyword names one
    movement: str | None  # the movement a cue word states
    role: str | None
    model: Triple | None = None  # the world model's nearest prototype, (identity, movement, role)
    sentence: dict[str, tuple[float, ...]] = field(default_factory=dict)  # fact -> the sentence reader's log-probs

    def fact_class(self) -> tuple[str, tuple[str, ...]]:
        """The class of the identity and its candidates, first the one the class's rate backs: the
        words' entity where they name one, else the model's. A text the sentence reader takes to be
        about no entity of the game is a class of its own ("guessed/agree/stray"), since a guess at
        the entity of a text about a dragon, or about nothing, is seldom right."""
        words = self.named or self.guessed
        said = "named" if self.named else "guessed" if self.guessed else "open"
        model = None if self.model is None else self.model[0]
        stray = "/stray" if self.stray else ""
        if model is None:
            return f"{said}/no-model{stray}", (words,) if words else ()
        if not words:
            return f"open/model{stray}", (model,)
        if model == words:
            return f"{said}/agree{stray}", (words,)
        return f"{said}/differ{stray}", (words, model)

    @property
    def stray(self) -> bool:
        """The sentence reader finds the text likelier about no entity of the game than about one."""
        subject = self.sentence.get("subject")
        return subject is not None and math.exp(subject[SUBJECTS.index("entity")]) < 0.5

    def features(self, name: str) -> np.ndarray:
        """[3, 3]: per value of a movement or role, the words' one-hot, the model's one-hot and the
        sentence reader's log-probability (0 where a reader says nothing)."""
        values = VALUES[name]
        words, model = getattr(self, name), None if self.model is None else self.model[FIELDS.index(name)]
        head = self.sentence.get(name, (0.0, 0.0, 0.0))
        return np.array([[float(words == v), float(model == v), head[k]] for k, v in enumerate(values)])


@dataclass
class Calibration:
    """A model's fitted reading (module docstring)."""

    identity: dict[str, dict]  # class -> {"first", "second": P(that candidate is true), "n"}
    weights: dict[str, list[float]]  # movement / role -> [words, model, sentence, bias per value (3)]
    sentence: SentenceReader | None = None  # the tuned sentence reader (None: words and model only)
    temperature: float = 1.0  # on the identities and roles of a manual's descriptions
    movement_temperature: float = 1.0
    fitted_on: dict = field(default_factory=dict)  # what it was fitted on, and how

    @classmethod
    def load(cls, path: str | Path) -> Calibration:
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
            calibration = cls(doc["identity"], doc["weights"], None, float(doc["temperature"]),
                              float(doc["movement_temperature"]), doc.get("fitted_on", {}))  # fmt: skip
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise LwmError(f"cannot read the reading calibration {path}: {exc}") from None
        if doc.get("sentence"):  # a file beside it
            calibration.sentence = SentenceReader.load(Path(path).parent / doc["sentence"])
        return calibration

    def save(self, path: str | Path) -> None:
        """reading.json, and the sentence reader beside it."""
        doc = {"temperature": self.temperature, "movement_temperature": self.movement_temperature,
               "identity": self.identity, "weights": self.weights, "fitted_on": self.fitted_on,
               "sentence": None if self.sentence is None else SENTENCE_FILE}  # fmt: skip
        Path(path).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        if self.sentence is not None:
            self.sentence.save(Path(path).parent / SENTENCE_FILE)

    def distribution(self, evidence: Evidence, name: str) -> dict[str, float]:
        """One fact of one description as a distribution over its values."""
        values = VALUES[name]
        if name != "identity":
            return dict(zip(values, fact_probs(evidence.features(name), self.weights[name]).tolist(), strict=True))
        cls, candidates = evidence.fact_class()
        rates = self.identity.get(cls)
        if not candidates or rates is None:  # a class the fit never saw backs nothing
            return {v: 1 / len(values) for v in values}
        out = dict.fromkeys(values, 0.0)
        spent = 0.0
        for value, rate in zip(candidates, (rates["first"], rates.get("second", 0.0)), strict=False):
            out[value] += rate
            spent += rate
        rest = [v for v in values if v not in candidates]
        for v in rest:
            out[v] += (1 - spent) / len(rest)
        return out


def fact_probs(features: np.ndarray, weights: Sequence[float]) -> np.ndarray:
    """[..., 3] a movement's or role's probabilities from its features [..., 3, 3]
    (`Evidence.features`) and weights [words, model, sentence, bias x 3]."""
    w = np.asarray(weights, dtype=np.float64)
    z = features @ w[:3] + w[3:]
    z = z - z.max(-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(-1, keepdims=True)


def fit_identity_rates(
    evidence: Sequence[Evidence], truth: Sequence[str], weights: Sequence[float], prior: float = 1.0
) -> dict[str, dict]:
    """Per identity class: how often its first candidate is the truth and how often its second,
    counted over descriptions of known truth, each with its weight (with `prior` pseudo-counts at
    chance)."""
    counts: dict[str, list[float]] = {}  # class -> [first, second, weight, n]
    for ev, true, w in zip(evidence, truth, weights, strict=True):
        cls, candidates = ev.fact_class()
        if not candidates:
            continue
        c = counts.setdefault(cls, [0.0, 0.0, 0.0, 0])
        c[2] += w
        c[3] += 1
        for slot, value in enumerate(candidates[:2]):
            c[slot] += w * (value == true)
    chance = 1 / len(IDENTITIES)
    rates = {}
    for cls, (first, second, seen, n) in counts.items():
        rates[cls] = {"first": round((first + prior * chance) / (seen + prior), 4), "n": n}
        if "/differ" in cls:
            rates[cls]["second"] = round((second + prior * chance) / (seen + prior), 4)
    return rates


def fit_fact_weights(features: np.ndarray, truth: np.ndarray, weights: np.ndarray) -> list[float]:
    """The weights of one fact (`fact_probs`) of highest weighted log-likelihood: features
    [N, 3, 3], true value indices [N], description weights [N]."""
    import torch

    x = torch.as_tensor(features, dtype=torch.float64)
    y, wt = torch.as_tensor(truth), torch.as_tensor(weights, dtype=torch.float64)
    params = torch.zeros(6, dtype=torch.float64, requires_grad=True)
    opt = torch.optim.LBFGS([params], max_iter=300, line_search_fn="strong_wolfe")

    def loss():
        opt.zero_grad()
        out = (torch.nn.functional.cross_entropy(x @ params[:3] + params[3:], y, reduction="none") * wt).sum()
        out = out / wt.sum()
        out.backward()
        return out

    opt.step(loss)
    return [round(float(v), 5) for v in params.detach()]


@dataclass(frozen=True)
class Question:
    """A question to the person about one fact of one board entity, with the answers it offers."""

    entity: str  # the identity on the board
    field: str  # "movement" or "role"
    choices: tuple[str, ...]  # the values, likeliest first
    p: float  # how sure the reading is of its likeliest value

    @property
    def text(self) -> str:
        if self.field == "movement":
            options = [ASKED_MOVEMENT[c] for c in self.choices]
            return f"Does the {self.entity} {', '.join(options[:-1])} or {options[-1]}?"
        options = [ROLE_WORDS[c] for c in self.choices]
        return f"Is the {self.entity} {', '.join(options[:-1])} or {options[-1]}?"

    def to_json(self) -> dict:
        words = MOVEMENT_WORDS if self.field == "movement" else ROLE_WORDS
        return {"entity": self.entity, "field": self.field, "text": self.text, "p": round(self.p, 3),
                "choices": [{"value": c, "words": words[c]} for c in self.choices]}  # fmt: skip


def fact_words(fact: Mapping) -> str:
    """A stated fact in plain words: "the airplane comes toward you", "the ship is the goal"."""
    words = MOVEMENT_WORDS if fact["field"] == "movement" else {r: f"is {w}" for r, w in ROLE_WORDS.items()}
    return f"the {fact['entity']} {words[fact['value']]}"


def check_fact(fact: Mapping, board: Sequence[str] | None = None) -> dict:
    """A stated fact {"entity", "field", "value"} checked; raises LwmError in plain words."""
    entity, name, value = fact.get("entity"), fact.get("field"), fact.get("value")
    if name not in ("movement", "role"):
        raise LwmError(f"a fact is about an entity's movement or role, not {name!r}")
    if value not in VALUES[name]:
        raise LwmError(f"{value!r} is no {name}; one of: {', '.join(VALUES[name])}")
    if entity not in IDENTITIES:
        raise LwmError(f"{entity!r} is no entity of the game")
    if board is not None and entity not in board:
        raise LwmError(f"the {entity} is not on this board ({', '.join(board)})")
    return {"entity": entity, "field": name, "value": value}


@dataclass
class ManualReading:
    """One manual read on one board (module docstring). `entities`: the board's identity ids,
    ascending; `p_map` [6, 6]: the probability that description j is about entity
    `entities[maps[m][j]]` and has role `ROLES[roles[r][j]]`; `movement` [6, 3, 3]: under map m,
    description j's movement distribution."""

    entities: tuple[int, ...]
    p_map: np.ndarray
    movement: np.ndarray
    facts: tuple[dict, ...] = ()

    maps = tuple(itertools.permutations(range(3)))
    roles = tuple(itertools.permutations(range(3)))

    # ------------------------------------------------------------------ marginals
    def _entity_of(self, m: int, j: int) -> int:
        return self.entities[self.maps[m][j]]

    def role_p(self, entity: int) -> np.ndarray:
        """[3]: P(entity has role ROLES[k])."""
        out = np.zeros(3)
        for m, r in np.ndindex(self.p_map.shape):
            j = self.maps[m].index(self.entities.index(entity))
            out[self.roles[r][j]] += self.p_map[m, r]
        return out

    def movement_p(self, entity: int) -> np.ndarray:
        """[3]: P(entity moves as MOVEMENTS[k])."""
        by_map = self.p_map.sum(1)
        out = np.zeros(3)
        for m in range(len(self.maps)):
            out += by_map[m] * self.movement[m, self.maps[m].index(self.entities.index(entity))]
        return out

    def about(self, entity: int) -> np.ndarray:
        """[3]: P(description j is about entity)."""
        by_map = self.p_map.sum(1)
        out = np.zeros(3)
        for m in range(len(self.maps)):
            out[self.maps[m].index(self.entities.index(entity))] += by_map[m]
        return out

    def assignments(self) -> tuple[list[tuple[int, int, int]], np.ndarray]:
        """Every way of giving the board entities the roles, as the ids of (enemy, message, goal),
        and its probability [6] (the order of `itertools.permutations(entities)`)."""
        options = [tuple(p) for p in itertools.permutations(self.entities)]
        p = np.zeros(len(options))
        for m, r in np.ndindex(self.p_map.shape):
            holder = [0, 0, 0]
            for j in range(3):
                holder[self.roles[r][j]] = self._entity_of(m, j)
            p[options.index(tuple(holder))] += self.p_map[m, r]
        return options, p

    def best(self) -> dict[int, dict]:
        """Per entity: its likeliest role and movement with their probabilities. The roles are the
        likeliest assignment's (each role once), so they never contradict one another."""
        options, p = self.assignments()
        top = options[int(np.argmax(np.round(p, 9)))]
        out = {}
        for e in self.entities:
            rp, mp = self.role_p(e), self.movement_p(e)
            k = int(np.argmax(np.round(mp, 9)))
            role = ROLES[top.index(e)]
            out[e] = {
                "role": role,
                "p": float(rp[ROLES.index(role)]),
                "movement": MOVEMENTS[k],
                "movement_p": float(mp[k]),
            }
        return out

    # ------------------------------------------------------------------ what a person sees
    def to_json(self) -> list[dict]:
        """Per board entity, ascending id: its likeliest role and movement, how sure of each, every
        value's probability, and which description it takes to be about it."""
        out = []
        for e, b in self.best().items():
            about = self.about(e)
            out.append({
                "identity": ID_TO_IDENTITY[e], "id": e, "role": b["role"], "p": round(b["p"], 3),
                "movement": b["movement"], "movement_p": round(b["movement_p"], 3),
                "roles": {r: round(float(v), 3) for r, v in zip(ROLES, self.role_p(e), strict=True)},
                "movements": {m: round(float(v), 3) for m, v in zip(MOVEMENTS, self.movement_p(e), strict=True)},
                "description": int(np.argmax(np.round(about, 9))), "description_p": round(float(about.max()), 3),
            })  # fmt: skip
        return out

    def answer(self) -> dict:
        """The reading as the imagine service's op `read` answers it (msgs_json/imagine_response)."""
        assignments, p = self.assignments()
        return {
            "reading": self.to_json(),
            "assignments": [list(a) for a in assignments],
            "assignment_p": [round(float(x), 6) for x in p],
            "questions": [q.to_json() for q in self.questions()],
            "facts": [dict(f) for f in self.facts],
        }

    def questions(self, below: float = ASK_BELOW, limit: int = MAX_QUESTIONS) -> list[Question]:
        """The facts the reading is least sure of, below `below`, least sure first (roles before
        movements on ties: a wrong role kills the agent, a wrong movement costs a detour)."""
        asked = []
        for e in self.entities:
            for name, p in (("role", self.role_p(e)), ("movement", self.movement_p(e))):
                if p.max() < below:
                    order = np.argsort(-np.round(p, 9), kind="stable")
                    choices = tuple(VALUES[name][k] for k in order)
                    asked.append(Question(ID_TO_IDENTITY[e], name, choices, float(p.max())))
        asked.sort(key=lambda q: (round(q.p, 6), q.field != "role", IDENTITIES[q.entity]))
        return asked[:limit]

    def configurations(self, limit: int = 27, mass: float = 0.999) -> list[tuple[tuple[Triple, ...], float]]:
        """The likeliest complete readings, each description's (identity, movement, role) and its
        probability, renormalised: the readings a world model imagines under (at most `limit`,
        fewer once they hold `mass`). Ties in a fixed order, so the same reading every time."""
        found = []
        for m, r in np.ndindex(self.p_map.shape):
            if self.p_map[m, r] <= 0:
                continue
            for moves in itertools.product(range(3), repeat=3):
                p = self.p_map[m, r] * np.prod([self.movement[m, j, moves[j]] for j in range(3)])
                if p > 0:
                    entity = [ID_TO_IDENTITY[self._entity_of(m, j)] for j in range(3)]
                    triples = tuple((entity[j], MOVEMENTS[moves[j]], ROLES[self.roles[r][j]])
                                    for j in range(3))  # fmt: skip
                    found.append((round(float(p), 12), triples))
        found.sort(key=lambda c: (-c[0], c[1]))
        kept, held = [], 0.0
        for p, triples in found[:limit]:
            kept.append((triples, p))
            held += p
            if held >= mass:
                break
        return [(t, p / held) for t, p in kept]


def read_manual(
    evidence: Sequence[Evidence], board: Sequence[int], calibration: Calibration, facts: Sequence[Mapping] = ()
) -> ManualReading:
    """The reading of a manual of three descriptions (their `evidence`) on a board of three entity
    ids, with the facts a person stated."""
    if len(evidence) != 3:
        raise LwmError(f"a manual has three descriptions, got {len(evidence)}")
    ident = [calibration.distribution(ev, "identity") for ev in evidence]
    entities = _completed(sorted({int(b) for b in board if b}), ident)
    names = [ID_TO_IDENTITY[e] for e in entities]
    stated = [check_fact(f, names) for f in facts]
    tau, tau_m = calibration.temperature, calibration.movement_temperature
    role = [calibration.distribution(ev, "role") for ev in evidence]
    move = np.array([[calibration.distribution(ev, "movement")[v] for v in MOVEMENTS] for ev in evidence])
    move = move**tau_m
    move /= move.sum(1, keepdims=True)
    maps, roles = ManualReading.maps, ManualReading.roles
    log_w = np.full((6, 6), -np.inf)
    movement = np.broadcast_to(move, (6, 3, 3)).copy()
    for m, mapping in enumerate(maps):
        about = [names[mapping[j]] for j in range(3)]
        base = sum(math.log(max(ident[j][about[j]], 1e-12)) for j in range(3))
        for f in stated:
            if f["field"] == "movement":
                j = about.index(f["entity"])
                movement[m, j] = [float(v == f["value"]) for v in MOVEMENTS]
        for r, given in enumerate(roles):
            if any(f["field"] == "role" and ROLES[given[about.index(f["entity"])]] != f["value"] for f in stated):
                continue
            log_w[m, r] = tau * (base + sum(math.log(max(role[j][ROLES[given[j]]], 1e-12)) for j in range(3)))
    w = np.exp(log_w - log_w.max())
    return ManualReading(entities, w / w.sum(), movement, tuple(stated))


def _completed(on_board: list[int], ident: list[dict[str, float]]) -> tuple[int, ...]:
    """The board's three entities: those in sight, and for each that left it (the message once
    picked up, the goal once reached) the identity the descriptions most likely name that is not
    in sight, so that the reading during an episode is the one its start was read with."""
    if len(on_board) > 3:
        raise LwmError(f"a board has three entities, got {len(on_board)}")
    out = list(on_board)
    while len(out) < 3:
        score = {IDENTITIES[n]: sum(d[n] for d in ident) for n in IDENTITIES if IDENTITIES[n] not in out}
        out.append(max(sorted(score), key=lambda i: score[i]))
    return tuple(sorted(out))


# ---------------------------------------------------------------------- the evidence
def word_evidence(texts: Sequence[str], encoder=None) -> list[Evidence]:
    """What the keyword parser says of each text (with `encoder`, the nearest name where no
    keyword names an entity)."""
    from ..text.parser import parse_identity, parse_movement, parse_role

    out = []
    for text in texts:
        named = parse_identity(text)
        guessed = parse_identity(text, encoder) if named is None and encoder is not None else None
        out.append(Evidence(named, guessed, parse_movement(text), parse_role(text)))
    return out


def model_readings(model, encoder, texts: Sequence[str]) -> list[Triple] | None:
    """Each text's nearest prototype as `model` reads it alone; None for a model without
    prototypes (only hedged models have them)."""
    if model is None or not hasattr(model, "proto_keys") or not hasattr(model, "_read_texts"):
        return None
    import torch

    from ..messenger.constants import ALL_TRIPLES
    from .hedged_reading import prototype_distances

    with torch.no_grad():
        keys, values = model._read_texts(encoder, list(texts))
        nearest = prototype_distances(keys, values, model.proto_keys, model.proto_values).argmin(-1)
    return [ALL_TRIPLES[int(n)] for n in nearest]


def evidence_for(model, encoder, texts: Sequence[str], sentence_reader: SentenceReader | None = None) -> list[Evidence]:
    """The readers' evidence on each text: the words (with `encoder`, its nearest name where no
    keyword names one), `model`'s own reading (None: no model) and the sentence reader's."""
    words = word_evidence(texts, encoder)
    read = model_readings(model, encoder, texts)
    sentence: list[dict] = [{} for _ in texts]
    if sentence_reader is not None and texts:
        for name, rows in sentence_reader.log_probs(texts).items():
            for k, lp in enumerate(rows):
                sentence[k][name] = tuple(round(float(v), 5) for v in lp)
    return [Evidence(w.named, w.guessed, w.movement, w.role, None if read is None else read[k], sentence[k])
            for k, w in enumerate(words)]  # fmt: skip


def fit_anchors(model, encoder, texts_by_triple: Mapping[Triple, Sequence[str]]) -> tuple:
    """Each triple's anchor (keys, values [108, W]): what `model` reads from the description of that
    triple whose reading lies nearest the mean of its readings, among `texts_by_triple` (the text
    it was trained on: the dataset's training and dev descriptions; the generator's where those
    have none)."""
    import torch

    from ..messenger.constants import ALL_TRIPLES

    keys, values = [], []
    with torch.no_grad():
        for t in ALL_TRIPLES:
            k, v = model._read_texts(encoder, list(texts_by_triple[t]))
            typical = int(((k - k.mean(0)).pow(2).sum(1) + (v - v.mean(0)).pow(2).sum(1)).argmin())
            keys.append(k[typical])
            values.append(v[typical])
    return torch.stack(keys), torch.stack(values)


def save_anchors(path: str | Path, keys, values) -> None:
    from safetensors.torch import save_file

    save_file({"keys": keys.half().contiguous(), "values": values.half().contiguous()}, str(path))


def load_anchors(path: str | Path) -> tuple:
    """The anchors beside a checkpoint (`fit_anchors`), as float32 tensors."""
    from safetensors.torch import load_file

    try:
        found = load_file(str(path))
        return found["keys"].float(), found["values"].float()
    except (OSError, KeyError, RuntimeError) as exc:
        raise LwmError(f"cannot read the reading's anchors {path}: {exc}") from None


def calibration_for(checkpoint: str | Path | None) -> Calibration:
    """The calibration shipped beside a checkpoint; the words-only one for a model without one."""
    if checkpoint is not None and (Path(checkpoint) / CALIBRATION_FILE).is_file():
        return Calibration.load(Path(checkpoint) / CALIBRATION_FILE)
    return Calibration.load(Path(__file__).resolve().parents[1] / "text" / "words_reading.json")


__all__ = [
    "ASK_BELOW",
    "Calibration",
    "Evidence",
    "ManualReading",
    "Question",
    "calibration_for",
    "check_fact",
    "fact_words",
    "evidence_for",
    "fit_anchors",
    "load_anchors",
    "save_anchors",
    "fact_probs",
    "fit_fact_weights",
    "fit_identity_rates",
    "model_readings",
    "read_manual",
    "word_evidence",
]

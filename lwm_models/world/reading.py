"""Which entity a world model reads each description of a manual as being about.

A person who writes "the hound runs off" about a board without a dog needs to hear it before a plan
is shown, from the world model itself rather than from a separate parser that may read the text
differently.

- EMMA-LWM: each entity's id vector queries the descriptions (`DescriptionAttention`); within one
  manual the entity attends to its own description. The raw scores are not comparable across
  identities (some id vectors score every description high), so each identity's scores are
  standardised by their mean and spread over reference descriptions (three generated descriptions
  of each of the 108 triples, computed once per model). The identity with the highest standardised
  score is the one the model reads the description as about.
- GPTHard: the identity its router gave the description (the keyword parser).
- A hedged EMMA-LWM (hedged_reading.py): as EMMA-LWM, from the attention of its own reading.
- A model that reads no text reads no identity.

`benchmarks/language_robustness.py` measures how often this is the description's true identity.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ..messenger.constants import ALL_TRIPLES, ID_TO_IDENTITY, IDENTITIES
from .base import WorldModel
from .frozen_text import FrozenTextEncoder
from .manual import ManualBatch

IDENTITY_IDS = sorted(set(IDENTITIES.values()))
REFERENCE_PER_TRIPLE = 3


def attention_scores(model: WorldModel, manual: ManualBatch) -> torch.Tensor:
    """[B, 3, 12] the query of every identity's id vector against each description's key."""
    tokens = model.text_encoder(manual.features, manual.mask)
    reader = model.reader
    keys = reader.k(reader.key_pool(tokens, manual.mask))  # [B, 3, W]
    queries = reader.q(model.obs_embedding(torch.tensor(IDENTITY_IDS)))  # [12, W]
    return torch.einsum("iw,bdw->bdi", queries, keys)


def _reference_texts() -> list[str]:
    from ..text.generator import generate_descriptions

    texts = []
    for triple in ALL_TRIPLES:
        found = generate_descriptions(triple)
        step = max(1, len(found) // REFERENCE_PER_TRIPLE)
        texts.extend(found[::step][:REFERENCE_PER_TRIPLE])
    return texts


@torch.inference_mode()
def _calibration(model: WorldModel, encoder: FrozenTextEncoder) -> tuple[torch.Tensor, torch.Tensor]:
    cached = getattr(model, "_identity_calibration", None)
    if cached is None:
        features, lengths = encoder.encode_arrays(_reference_texts())
        feats = torch.from_numpy(features).float()[None]
        mask = torch.arange(feats.shape[2])[None, None, :] < torch.from_numpy(lengths)[None, :, None]
        scores = attention_scores(model, ManualBatch(feats, mask))[0]
        cached = (scores.mean(0), scores.std(0).clamp(min=1e-6))
        model._identity_calibration = cached
    return cached


@torch.inference_mode()
def read_identities(
    model: WorldModel, encoder: FrozenTextEncoder | None, descriptions: Sequence[str]
) -> list[str | None]:
    """The identity `model` reads each description as about (None: it reads no text)."""
    if hasattr(model, "routed_identity"):  # GPTHard: the entity its words route it to
        return [ID_TO_IDENTITY.get(int(model.routed_identity(d, encoder))) for d in descriptions]
    if not model.reads_text or encoder is None or not hasattr(model, "reader"):
        return [None] * len(descriptions)
    encoder = encoder.keeping(model.config.text.max_tokens)
    was_training = model.training
    model.eval()
    mean, std = _calibration(model, encoder)
    features, mask = encoder.encode(list(descriptions))
    scores = attention_scores(model, ManualBatch(features[None].float(), mask[None]))[0]
    model.train(was_training)
    best = ((scores - mean) / std).argmax(-1)
    return [ID_TO_IDENTITY[IDENTITY_IDS[int(i)]] for i in best]


def unsure_fields(model: WorldModel, manual: ManualBatch, descriptions: Sequence[str]) -> list[dict] | None:
    """Per description, what its words leave open and whether the world model filled it in itself
    (`guessed`) or imagines each possibility: a hedged EMMA-LWM (world/hedged_reading.py) knows
    both; a model that reads text but not the words' facts always guesses, and what is open is
    the movement or role no keyword states; None for a model that reads no text."""
    unsure = getattr(model, "unsure", None)
    if unsure is not None:
        return unsure(manual)
    if not model.reads_text:
        return None
    from ..text.parser import parse_movement, parse_role

    out = []
    for text in descriptions:
        said = {"movement": parse_movement(text), "role": parse_role(text)}
        out.append({"open": [f for f, v in said.items() if v is None], "guessed": True})
    return out


def grounding(
    read: Sequence[str | None],
    board: Sequence[str],
    unsure: Sequence[dict] | None = None,
    grounded: Sequence[Sequence[str]] | None = None,
) -> list[dict]:
    """Per description: the identity read, whether that entity is on the board, (a model that
    grounds its words, `grounded`: the board entities each description is taken as about) the
    board entity it takes a description read as about another as about (`grounded_as`), or the
    board entities a description is one of (`grounded_among`, each of them a different
    description's), and (hedged models) what the words leave open and whether the world model
    guessed it."""
    out = [{"identity": r, "on_board": r is not None and r in board} for r in read]
    for entry, g in zip(out, grounded or []):
        if len(g) == 1 and not entry["on_board"] and g[0] in board:
            entry["grounded_as"] = g[0]
        elif len(g) > 1:
            entry["grounded_among"] = list(g)
    for entry, u in zip(out, unsure or []):
        if u["open"]:
            entry["unsure"] = list(u["open"])
            entry["guessed"] = bool(u["guessed"])
    return out


def ungrounded_note(
    descriptions: Sequence[str],
    read: Sequence[str | None],
    board: Sequence[str],
    grounded: Sequence[Sequence[str]] | None = None,
) -> str | None:
    """What to tell a person whose descriptions the world model reads as about entities that are
    not on the board (and, for a model that grounds its words, `grounded`, which board entity it
    takes each as about instead), or whose words it shares out among the board's entities; None
    when there is nothing to say."""
    notes = []
    off = [(i, r) for i, r in enumerate(read) if r is not None and r not in board]
    if off:
        said = " and ".join(f'"{_short(descriptions[i])}" as about the {r}' for i, r in off)
        note = f"the world model reads {said}, not on this board ({', '.join(board)})"
        # Grounding takes a description alone only when it is the one left (ground_words), so
        # "it" is the description just quoted.
        taken = [grounded[i][0] for i, _ in off if grounded and len(grounded[i]) == 1 and grounded[i][0] in board]
        if taken:
            note += f"; it takes it as about the {taken[0]}, the one entity on the board no other description names"
        notes.append(note)
    shared = [i for i, g in enumerate(grounded or []) if len(g) > 1]
    if shared:
        quoted = " and ".join(f'"{_short(descriptions[i])}"' for i in shared)
        entities = " and the ".join(grounded[shared[0]])
        notes.append(f"it takes {quoted} as about the {entities}, one each, and imagines each way round")
    return "; ".join(notes) or None


def unsure_note(descriptions: Sequence[str], unsure: Sequence[dict] | None) -> str | None:
    """What to tell a person whose words leave something open (unsaid, or said in a way the keyword
    parser and the encoder read differently), or None."""
    said = []
    for text, u in zip(descriptions, unsure or []):
        if u["open"]:
            how = "the world model guessed" if u["guessed"] else "the world model imagines each possibility"
            said.append(f'"{_short(text)}" leaves its {" and ".join(u["open"])} unclear ({how})')
    return None if not said else "; ".join(said) + ": say it plainly to fix it"


def _short(text: str, limit: int = 48) -> str:
    return text if len(text) <= limit else text[: limit - 3].rstrip() + "..."


__all__ = ["attention_scores", "grounding", "read_identities", "ungrounded_note", "unsure_fields", "unsure_note"]

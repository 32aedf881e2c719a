"""A manual in the form the models read: `ManualBatch`, and the checks and text encoding every
reader of a manual shares (each world-model kind adds what else it needs in `read_manual`; the
policy reads the text alone)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch

from ..errors import LwmError

if TYPE_CHECKING:
    from .frozen_text import FrozenTextEncoder


class ManualError(LwmError, ValueError):
    """A manual that a model cannot read (wrong count, empty text, missing parse)."""


@dataclass
class ManualBatch:
    """The manuals of a batch, in the forms the families need.

    features: [B, 3, T, F] frozen text-encoder token vectors of each description.
    mask: [B, 3, T] True at real (non-padding) tokens.
    parse: [B, 3, 3] long, per description the true (identity id, movement index, role index).
    routed: [B, 3] long, per description the identity id an external parser assigned (GPTHard),
        or what its words decide (hedged models, `hedged_reading.words_code`).
    among: [B, 3, 17] bool, per description the entity ids it may be about on its board (a hedged
        model grounding its words, `hedged_reading.ground_words`); None: any.
    evidence: a batch-of-one manual's evidence per description for its reading
        (`manual_reading.Evidence`, a model with a reading calibration); None: not read that way.
    facts: what a person stated of the board's entities ({"entity", "field", "value"}), which the
        reading holds for sure.
    reading: the manual read on its board (`manual_reading.ManualReading`, set by `on_board`).
    """

    features: torch.Tensor | None = None
    mask: torch.Tensor | None = None
    parse: torch.Tensor | None = None
    routed: torch.Tensor | None = None
    among: torch.Tensor | None = None
    evidence: list | None = None
    facts: tuple = ()
    reading: object | None = field(default=None, compare=False)

    def index(self, idx: torch.Tensor) -> ManualBatch:
        fields = (self.features, self.mask, self.parse, self.routed, self.among)
        return ManualBatch(*(None if t is None else t[idx] for t in fields))


def text_manual(descriptions: Sequence[str], encoder: FrozenTextEncoder | None) -> ManualBatch:
    """A batch-of-one ManualBatch of three descriptions: their encoded tokens if `encoder` is
    given, nothing else (a kind that reads more adds it)."""
    if len(descriptions) != 3:
        raise ManualError(f"a manual has exactly 3 descriptions, got {len(descriptions)}")
    for i, d in enumerate(descriptions):
        if not isinstance(d, str) or not d.strip():
            raise ManualError(f"description {i} is empty or not text")
    if encoder is None:
        return ManualBatch()
    features, mask = encoder.encode(list(descriptions))
    return ManualBatch(features[None], mask[None])

"""Turn a manual (three descriptions, and the true parse when a skyline needs it) into the
ManualBatch a world model reads. Used by imagination, the agent and the ROS simulator node."""

from __future__ import annotations

from collections.abc import Sequence

import torch

from ..errors import LwmError
from ..messenger.constants import IDENTITIES, MOVEMENTS, ROLES, Triple
from .base import ManualBatch
from .frozen_text import FrozenTextEncoder
from .registry import NEEDS_TEXT


class ManualError(LwmError, ValueError):
    """A manual that a world model cannot read (wrong count, empty text, missing parse)."""


def manual_batch(
    kind: str,
    descriptions: Sequence[str],
    encoder: FrozenTextEncoder | None,
    parse: Sequence[Triple] | None = None,
) -> ManualBatch:
    """A batch-of-one ManualBatch for a model of `kind`."""
    if len(descriptions) != 3:
        raise ManualError(f"a manual has exactly 3 descriptions, got {len(descriptions)}")
    for i, d in enumerate(descriptions):
        if not isinstance(d, str) or not d.strip():
            raise ManualError(f"description {i} is empty or not text")
    features = mask = parse_t = routed = None
    if NEEDS_TEXT.get(kind, False):
        if encoder is None:
            raise ManualError(f"a {kind} model needs a text encoder")
        f, m = encoder.encode(list(descriptions))
        features, mask = f[None], m[None]
    if kind == "oracle":
        if parse is None or len(parse) != 3:
            raise ManualError("OracleParse needs the true (identity, movement, role) of each description")
        try:
            codes = [[IDENTITIES[i], MOVEMENTS.index(m), ROLES.index(r)] for i, m, r in parse]
        except (KeyError, ValueError) as exc:
            raise ManualError(f"bad parse {parse!r}: {exc}") from None
        parse_t = torch.tensor([codes])
    if kind == "gpthard":
        from ..text.parser import route_identity_id

        routed = torch.tensor([[route_identity_id(d) for d in descriptions]])
    return ManualBatch(features, mask, parse_t, routed)

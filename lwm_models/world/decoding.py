"""Which path decodes imagination. Every path samples the same tokens for the same seed (see each):

- "speculative" (the default): the flat decoder, drafting each step's block and checking it in one
  call (world/speculative.py); the tokens of the reference path up to floating-point rounding.
- "flat": the flat decoder, one token per call as the reference path (world/flat_decoder.py).
- "reference": the model's own modules, one token per call (imagine.DecoderBatch): the definition the
  others are tested against (tests/test_fast_imagination.py).

A model the flat decoder does not run (Standard's cross-attention), or imagination without a KV
cache, uses the reference path whatever is asked. The environment variable LWM_DECODING sets the
default of a process (e.g. to measure a server on the reference path).
"""

from __future__ import annotations

import os

from .base import WorldModel
from .flat_decoder import supports
from .imagine import DecoderBatch
from .speculative import FlatDecoderBatch

DECODINGS = ("speculative", "flat", "reference")


def default_decoding() -> str:
    name = os.environ.get("LWM_DECODING", "speculative")
    if name not in DECODINGS:
        raise ValueError(f"LWM_DECODING must be one of {', '.join(DECODINGS)}, got {name!r}")
    return name


def make_decoder_batch(
    model: WorldModel, decoding: str | None = None, use_cache: bool = True, first_blocks: int = 0
) -> DecoderBatch:
    """The rows of a batch of imagination, decoded by `decoding` (None: the default)."""
    decoding = decoding or default_decoding()
    if decoding not in DECODINGS:
        raise ValueError(f"decoding must be one of {', '.join(DECODINGS)}, got {decoding!r}")
    if decoding == "reference" or not use_cache or not supports(model):
        return DecoderBatch(model, use_cache, first_blocks)
    return FlatDecoderBatch(model, first_blocks, lookahead=-1 if decoding == "speculative" else 0)


__all__ = ["DECODINGS", "default_decoding", "make_decoder_batch"]

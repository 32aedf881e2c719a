"""Standard: an encoder-decoder Transformer. Every decoder block cross-attends (multi-head) to all
description tokens of the manual; nothing is routed to entities explicitly."""

from __future__ import annotations

from dataclasses import replace

from .base import Conditioning, ManualBatch, WorldModel, WorldModelConfig
from .description_encoder import DescriptionEncoder


class StandardLWM(WorldModel):
    kind = "standard"
    reads_text = True

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config, replace(config.decoder, cross_attention=True))
        self.text_encoder = DescriptionEncoder(config.text, config.decoder.hidden, config.decoder.dropout)
        self._init()

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.features is None or manual.mask is None:
            raise ValueError("Standard needs the manual's encoded descriptions")
        tokens = self.text_encoder(manual.features, manual.mask)  # [B, 3, T, H]
        b, d, t, h = tokens.shape
        mask = manual.mask.reshape(b, d * t).clone()
        mask[:, 0] |= ~mask.any(-1)
        return Conditioning(memory=tokens.reshape(b, d * t, h), memory_mask=mask)

"""GPTHard: descriptions routed to entities by an external parser's identity guess.

The paper asked ChatGPT which entity each description is about; here the router is the project's
own offline parser (lwm_models.text.parser), whose guesses arrive as `manual.routed` (an identity
id per description, 0 when the parser has no guess). Each description's pooled value is added to
the id token of the identity it was routed to (summed if two are routed to the same one).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..messenger.constants import NUM_IDS, Triple
from ..text.parser import route_identity_id
from .base import Conditioning, ManualBatch, WorldModel, WorldModelConfig
from .description_encoder import AttentionPool, DescriptionEncoder
from .frozen_text import FrozenTextEncoder
from .gpt import zero_init


class GPTHardLWM(WorldModel):
    kind = "gpthard"
    reads_text = True
    route = staticmethod(route_identity_id)  # description -> identity id (0: no guess)

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        h = config.decoder.hidden
        self.text_encoder = DescriptionEncoder(config.text, h, config.decoder.dropout)
        self.value_pool = AttentionPool(h)
        self.v_proj = nn.Linear(h, h)
        self._init()
        zero_init(self.v_proj)  # as in EMMA-LWM: the routed values start at zero

    def read_manual(
        self, descriptions: Sequence[str], encoder: FrozenTextEncoder | None, parse: Sequence[Triple] | None = None
    ) -> ManualBatch:
        batch = super().read_manual(descriptions, encoder)
        batch.routed = torch.tensor([[self.route(d) for d in descriptions]])
        return batch

    def routed_identity(self, text: str, encoder: FrozenTextEncoder | None = None) -> int:
        """The identity id a description is routed to (0: none)."""
        return self.route(text)

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.features is None or manual.routed is None:
            raise ValueError("GPTHard needs the encoded descriptions and the parser's routing")
        values = self.v_proj(self.value_pool(self.text_encoder(manual.features, manual.mask), manual.mask))
        table = torch.zeros(values.shape[0], NUM_IDS, values.shape[-1], dtype=values.dtype, device=values.device)
        table.scatter_add_(1, manual.routed.clamp(0, NUM_IDS - 1).unsqueeze(-1).expand_as(values), values)
        table[:, 0] = 0  # unrouted descriptions condition nothing
        return Conditioning(id_table=table)

"""EMMA-LWM and the Observational baseline.

EMMA-LWM: each description yields a key and a value (two attention pools over its encoded
tokens). The embedding of every entity-channel id token queries the three keys (single-head
dot-product attention, its own projections, scale 1/sqrt(H), softmax over the descriptions) and
the attended value is added to that id token's embedding, in every block, before positions.

Departure from the paper, measured: the value projection starts at zero, so EMMA-LWM starts as
the Observational model and learns to add what it reads. With the default N(0, 0.02) init the
attended values were about ten times the norm of the id-token embeddings they are added to, and
drowned the identity while the model was young: at step 500 of the same CPU recipe EMMA-LWM's
NewAll-dev loss was 1.38 against Observational's 0.66 (train loss 1.01 vs 0.52 at step 750).

Observational: the same decoder without the manual. (The paper zeroes the manual encoding; here
no vector is added at all, which differs only by a learned constant bias on the id tokens.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import torch
from torch import nn

from ..messenger.constants import NUM_IDS
from .base import Conditioning, ManualBatch, WorldModel
from .description_encoder import AttentionPool, DescriptionEncoder, TextConfig
from .gpt import DecoderConfig


def zero_init(linear: nn.Linear) -> None:
    """Start a residual contribution at zero (see the module docstring)."""
    nn.init.zeros_(linear.weight)
    nn.init.zeros_(linear.bias)


@dataclass
class EmmaConfig:
    decoder: DecoderConfig = field(default_factory=DecoderConfig)
    text: TextConfig = field(default_factory=TextConfig)


class EmmaLWM(WorldModel):
    kind = "emma"

    def __init__(self, config: EmmaConfig) -> None:
        super().__init__(config.decoder)
        self.config = config
        h = config.decoder.hidden
        self.text_encoder = DescriptionEncoder(config.text, h, config.decoder.dropout)
        self.key_pool = AttentionPool(h)
        self.value_pool = AttentionPool(h)
        self.q_proj = nn.Linear(h, h)
        self.k_proj = nn.Linear(h, h)
        self.v_proj = nn.Linear(h, h)
        self._init()
        zero_init(self.v_proj)

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.features is None or manual.mask is None:
            raise ValueError("EMMA-LWM needs the manual's encoded descriptions")
        tokens = self.text_encoder(manual.features, manual.mask)  # [B, 3, T, H]
        keys = self.k_proj(self.key_pool(tokens, manual.mask))  # [B, 3, H]
        values = self.v_proj(self.value_pool(tokens, manual.mask))
        ids = torch.arange(NUM_IDS, device=tokens.device)
        queries = self.q_proj(self.obs_embedding(ids))  # [17, H]: every possible id token
        scores = torch.einsum("ih,bdh->bid", queries, keys) / math.sqrt(keys.shape[-1])
        table = torch.einsum("bid,bdh->bih", torch.softmax(scores, dim=-1), values)  # [B, 17, H]
        return Conditioning(id_table=table)

    def attention_over_descriptions(self, manual: ManualBatch, ids: torch.Tensor) -> torch.Tensor:
        """[B, len(ids), 3] attention of the given id tokens over the descriptions (to inspect
        which description the model reads for which entity)."""
        tokens = self.text_encoder(manual.features, manual.mask)
        keys = self.k_proj(self.key_pool(tokens, manual.mask))
        queries = self.q_proj(self.obs_embedding(ids))
        return torch.softmax(torch.einsum("ih,bdh->bid", queries, keys) / math.sqrt(keys.shape[-1]), dim=-1)


class ObservationalLWM(WorldModel):
    kind = "observational"

    def __init__(self, config: EmmaConfig) -> None:
        super().__init__(config.decoder)
        self.config = config
        self._init()

    def condition(self, manual: ManualBatch) -> Conditioning:
        return Conditioning()

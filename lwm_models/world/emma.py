"""EMMA-LWM and the Observational baseline.

EMMA-LWM: the descriptions' encoded tokens are read by `DescriptionAttention` (the module the
policy reads the manual with too), with the model's own embedding of each id token as the query;
what id i reads is added to the embedding of every entity-channel id token equal to i, before
positions.

Departure from the paper, measured: the value projection starts at zero, so EMMA-LWM starts as
the Observational model and learns to add what it reads. With the default N(0, 0.02) init the
attended values were about ten times the norm of the id-token embeddings they are added to, and
drowned the identity while the model was young: at step 500 of the same CPU recipe EMMA-LWM's
NewAll-dev loss was 1.38 against Observational's 0.66 (train loss 1.01 vs 0.52 at step 750).

Observational: the same decoder without the manual. (The paper zeroes the manual encoding; here
no vector is added at all, which differs only by a learned constant bias on the id tokens.)
"""

from __future__ import annotations

import torch

from ..messenger.constants import NUM_IDS
from .base import Conditioning, ManualBatch, WorldModel, WorldModelConfig
from .description_attention import DescriptionAttention
from .description_encoder import DescriptionEncoder
from .gpt import zero_init


class EmmaLWM(WorldModel):
    kind = "emma"
    reads_text = True

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        h = config.decoder.hidden
        self.text_encoder = DescriptionEncoder(config.text, h, config.decoder.dropout)
        self.reader = DescriptionAttention(h, project_values=True)
        self._init()
        zero_init(self.reader.v)

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.features is None or manual.mask is None:
            raise ValueError("EMMA-LWM needs the manual's encoded descriptions")
        tokens = self.text_encoder(manual.features, manual.mask)  # [B, 3, T, H]
        ids = torch.arange(NUM_IDS, device=tokens.device)
        return Conditioning(id_table=self.reader(tokens, manual.mask, self.obs_embedding(ids)))


class ObservationalLWM(WorldModel):
    kind = "observational"

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        self._init()

    def condition(self, manual: ManualBatch) -> Conditioning:
        return Conditioning()

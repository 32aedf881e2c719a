"""OracleParse: the skyline that is told each entity's true identity, movement and role.

The embeddings of the three are summed and added to that entity's id token, in every block.
"""

from __future__ import annotations

import torch
from torch import nn

from ..messenger.constants import MOVEMENTS, NUM_IDS, ROLES
from .base import Conditioning, ManualBatch, WorldModel
from .emma import EmmaConfig


class OracleParseLWM(WorldModel):
    kind = "oracle"

    def __init__(self, config: EmmaConfig) -> None:
        super().__init__(config.decoder)
        self.config = config
        h = config.decoder.hidden
        self.identity_emb = nn.Embedding(NUM_IDS, h)
        self.movement_emb = nn.Embedding(len(MOVEMENTS), h)
        self.role_emb = nn.Embedding(len(ROLES), h)
        self._init()

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.parse is None:
            raise ValueError("OracleParse needs the true parse of the manual")
        ident, mov, role = manual.parse.unbind(-1)  # [B, 3] each
        vec = self.identity_emb(ident) + self.movement_emb(mov) + self.role_emb(role)
        table = torch.zeros(ident.shape[0], NUM_IDS, vec.shape[-1], dtype=vec.dtype, device=vec.device)
        table.scatter_add_(1, ident.unsqueeze(-1).expand_as(vec), vec)
        return Conditioning(id_table=table)

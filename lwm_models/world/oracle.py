"""OracleParse: the skyline that is told each entity's true identity, movement and role.

The embeddings of the three are summed and added to that entity's id token, in every block.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from ..messenger.constants import IDENTITIES, MOVEMENTS, NUM_IDS, ROLES, Triple
from .base import Conditioning, ManualBatch, WorldModel, WorldModelConfig
from .frozen_text import FrozenTextEncoder
from .manual import ManualError, text_manual


class OracleParseLWM(WorldModel):
    kind = "oracle"
    needs_parse = True

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        h = config.decoder.hidden
        self.identity_emb = nn.Embedding(NUM_IDS, h)
        self.movement_emb = nn.Embedding(len(MOVEMENTS), h)
        self.role_emb = nn.Embedding(len(ROLES), h)
        self._init()

    def read_manual(
        self, descriptions: Sequence[str], encoder: FrozenTextEncoder | None, parse: Sequence[Triple] | None = None
    ) -> ManualBatch:
        batch = text_manual(descriptions, None)
        if parse is None or len(parse) != 3:
            raise ManualError("OracleParse needs the true (identity, movement, role) of each description")
        try:
            codes = [[IDENTITIES[i], MOVEMENTS.index(m), ROLES.index(r)] for i, m, r in parse]
        except (KeyError, ValueError) as exc:
            raise ManualError(f"bad parse {parse!r}: {exc}") from None
        batch.parse = torch.tensor([codes])
        return batch

    def condition(self, manual: ManualBatch) -> Conditioning:
        if manual.parse is None:
            raise ValueError("OracleParse needs the true parse of the manual")
        ident, mov, role = manual.parse.unbind(-1)  # [B, 3] each
        vec = self.identity_emb(ident) + self.movement_emb(mov) + self.role_emb(role)
        table = torch.zeros(ident.shape[0], NUM_IDS, vec.shape[-1], dtype=vec.dtype, device=vec.device)
        table.scatter_add_(1, ident.unsqueeze(-1).expand_as(vec), vec)
        return Conditioning(id_table=table)

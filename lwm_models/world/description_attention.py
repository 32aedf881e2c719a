"""What each entity reads from the manual: the attention of an entity id over the descriptions.

EMMA (Zhong et al., 2020) and EMMA-LWM read a manual the same way, and the world model and the
policy share this module: each description gives a key and a value (two attention pools over its
token vectors); the vector of every entity id (0-16) queries the three keys (single-head
dot-product attention, scale 1/sqrt(width), softmax over the descriptions) and gets the
attended value. The result is a table [B, 17, width] computed once per manual; the caller adds
(world model) or paints (policy) row i wherever id i appears.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from .description_encoder import AttentionPool


class DescriptionAttention(nn.Module):
    """Args:
    width: width of the description token vectors, the id vectors and the result.
    project_values: a linear projection of the pooled values (EMMA-LWM); the policy reads
        the pooled values as they are.
    """

    def __init__(self, width: int, project_values: bool) -> None:
        super().__init__()
        self.key_pool = AttentionPool(width)
        self.value_pool = AttentionPool(width)
        self.q = nn.Linear(width, width)
        self.k = nn.Linear(width, width)
        self.v = nn.Linear(width, width) if project_values else None

    def read(self, tokens: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """tokens [B, 3, T, W] and mask [B, 3, T] of the descriptions -> each description's key and
        value [B, 3, W]."""
        keys = self.k(self.key_pool(tokens, mask))
        values = self.value_pool(tokens, mask)
        if self.v is not None:
            values = self.v(values)
        return keys, values

    def attend(self, keys: torch.Tensor, values: torch.Tensor, id_vectors: torch.Tensor) -> torch.Tensor:
        """keys and values [B, 3, W], id_vectors [17, W] (the query source of each id) -> [B, 17, W]:
        what each id reads."""
        scores = torch.einsum("iw,bdw->bid", self.q(id_vectors), keys) / math.sqrt(keys.shape[-1])
        return torch.einsum("bid,bdw->biw", torch.softmax(scores, dim=-1), values)

    def forward(self, tokens: torch.Tensor, mask: torch.Tensor, id_vectors: torch.Tensor) -> torch.Tensor:
        """tokens [B, 3, T, W] and mask [B, 3, T] of the descriptions, id_vectors [17, W] -> [B, 17, W]."""
        return self.attend(*self.read(tokens, mask), id_vectors)

"""The EMMA policy (§4): it reads the manual the way EMMA-LWM does and acts on the grid.

Each description gives a key and a value (attention pools over its frozen encoder tokens); every
entity's id embedding queries the keys and the attended value is painted into the entity's cell.
The avatar's cell gets the avatar's own embedding. The last 3 observations are stacked on the
channel axis, then a small convolution and an MLP give the logits of the 5 actions. It samples in
training and takes the argmax in evaluation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from ..messenger.constants import GRID, NUM_ACTIONS, NUM_IDS
from ..world.base import ManualBatch
from ..world.description_encoder import AttentionPool

HISTORY = 3


@dataclass
class PolicyConfig:
    """embed: width of entity and description vectors; conv: channels of the two convolutions;
    hidden: width of the MLP; feature_dim: the frozen text encoder's width."""

    embed: int = 64
    conv: int = 64
    hidden: int = 128
    feature_dim: int = 384


class EmmaPolicy(nn.Module):
    def __init__(self, config: PolicyConfig | None = None) -> None:
        super().__init__()
        self.config = c = config or PolicyConfig()
        self.text_proj = nn.Linear(c.feature_dim, c.embed)
        self.key_pool = AttentionPool(c.embed)
        self.value_pool = AttentionPool(c.embed)
        self.id_emb = nn.Embedding(NUM_IDS, c.embed)
        self.q = nn.Linear(c.embed, c.embed)
        self.k = nn.Linear(c.embed, c.embed)
        self.conv = nn.Sequential(
            nn.Conv2d(HISTORY * c.embed, c.conv, 2), nn.LeakyReLU(), nn.Conv2d(c.conv, c.conv, 2), nn.LeakyReLU()
        )
        self.mlp = nn.Sequential(
            nn.Linear(c.conv * (GRID - 2) ** 2, c.hidden), nn.LeakyReLU(), nn.Linear(c.hidden, NUM_ACTIONS)
        )

    def id_values(self, manual: ManualBatch) -> torch.Tensor:
        """[B, 17, E]: what each id token reads from the manual (computed once per manual)."""
        x = self.text_proj(manual.features)  # [B, 3, T, E]
        keys = self.k(self.key_pool(x, manual.mask))
        values = self.value_pool(x, manual.mask)
        q = self.q(self.id_emb.weight)  # [17, E]
        attn = torch.softmax(torch.einsum("ie,bde->bid", q, keys) / math.sqrt(keys.shape[-1]), dim=-1)
        return torch.einsum("bid,bde->bie", attn, values)

    def forward(self, history: torch.Tensor, id_values: torch.Tensor) -> torch.Tensor:
        """history: [B, 3, 4, 3] compact observations (oldest first); id_values: [B, 17, E].
        Returns action logits [B, 5]."""
        b = history.shape[0]
        e = self.config.embed
        grid = torch.zeros(b, HISTORY, GRID, GRID, e, dtype=id_values.dtype, device=id_values.device)
        h = history.long()
        ids, rows, cols = h[..., 0], h[..., 1], h[..., 2]  # [B, 3 frames, 4 channels]
        bi = torch.arange(b)[:, None, None].expand_as(ids)
        fi = torch.arange(HISTORY)[None, :, None].expand_as(ids)
        # Entities: their manual-derived vectors; the avatar: its own embedding.
        vec = torch.gather(id_values[:, None].expand(-1, HISTORY, -1, -1), 2, ids[..., None].expand(-1, -1, -1, e))
        is_avatar = torch.zeros_like(ids, dtype=torch.bool)
        is_avatar[..., 3] = True
        vec = torch.where(is_avatar[..., None], self.id_emb(ids), vec)
        present = ids > 0
        grid.index_put_((bi[present], fi[present], rows[present], cols[present]), vec[present], accumulate=True)
        x = grid.permute(0, 1, 4, 2, 3).reshape(b, HISTORY * e, GRID, GRID)
        return self.mlp(self.conv(x).flatten(1))


def stack_history(observations: np.ndarray) -> np.ndarray:
    """The last 3 observations of each trajectory [n, t, 4, 3] -> [n, 3, 4, 3], repeating the
    first observation while fewer than 3 exist."""
    obs = np.asarray(observations)
    t = obs.shape[1]
    idx = np.clip(np.arange(t - HISTORY, t), 0, t - 1)
    return obs[:, idx]


def act(
    policy: EmmaPolicy,
    history: np.ndarray,
    id_values: torch.Tensor,
    sample: bool,
    generator: torch.Generator | None = None,
) -> np.ndarray:
    """Actions for a batch: sampled (training) or argmax (evaluation)."""
    with torch.no_grad():
        logits = policy(torch.from_numpy(np.ascontiguousarray(history)), id_values)
    if sample:
        return torch.multinomial(torch.softmax(logits, -1), 1, generator=generator).squeeze(1).numpy()
    return logits.argmax(-1).numpy()

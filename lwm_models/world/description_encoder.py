"""The trainable part of the text side: frozen encoder token vectors -> per-description vectors.

Each description is processed separately: project the frozen encoder's token vectors to the
model width, run a small Transformer encoder over the tokens with padding masked (the original
did not mask padding; masking makes a description's encoding independent of how much padding
its batch has), then pool.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn


@dataclass
class TextConfig:
    """feature_dim: width of the frozen encoder's token vectors (all-MiniLM-L6-v2: 384).
    layers: Transformer encoder layers over each description's tokens (paper: 4).
    heads: attention heads of those layers.
    max_tokens: description length in encoder tokens, longer ones truncated (paper: 36).
    """

    feature_dim: int = 384
    layers: int = 4
    heads: int = 4
    max_tokens: int = 36


class AttentionPool(nn.Module):
    """A learned scalar score per token, softmax over the real tokens, weighted sum."""

    def __init__(self, hidden: int) -> None:
        super().__init__()
        self.score = nn.Linear(hidden, 1)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        scores = self.score(x).squeeze(-1).masked_fill(~mask, float("-inf"))
        weights = torch.softmax(scores, dim=-1).nan_to_num(0.0)  # an all-padding row pools to 0
        return torch.einsum("...t,...th->...h", weights, x)


class DescriptionEncoder(nn.Module):
    def __init__(self, text: TextConfig, hidden: int, dropout: float) -> None:
        super().__init__()
        self.proj = nn.Linear(text.feature_dim, hidden)
        layer = nn.TransformerEncoderLayer(
            hidden, text.heads, 4 * hidden, dropout, activation="gelu", batch_first=True, norm_first=True
        )
        self.encoder = nn.TransformerEncoder(layer, text.layers, enable_nested_tensor=False)
        self.ln = nn.LayerNorm(hidden)

    def forward(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """features [B, D, T, F], mask [B, D, T] -> token vectors [B, D, T, H]."""
        b, d, t, f = features.shape
        x = self.proj(features.reshape(b * d, t, f).to(self.proj.weight.dtype))
        m = mask.reshape(b * d, t)
        safe = m.clone()
        safe[:, 0] |= ~m.any(-1)  # a fully padded row would give NaNs; its output is masked later
        x = self.encoder(x, src_key_padding_mask=~safe)
        return self.ln(x).reshape(b, d, t, -1)

"""The GPT-style causal Transformer shared by every world-model family, with a KV cache.

Pre-LayerNorm blocks, learned absolute positions (in the world model), MLP 4x. A block can also
cross-attend to a memory (the Standard baseline's description tokens). The KV cache is
preallocated for the longest sequence, so imagination appends keys and values in place instead
of concatenating tensors at every token.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn


@dataclass
class DecoderConfig:
    """Sizes and regularisation of the decoder.

    hidden: width of every token vector (paper: 256).
    layers: number of Transformer blocks (paper: 4).
    heads: attention heads per block (paper: 4); hidden must divide by it.
    dropout: dropout on embeddings, residual branches and MLPs (paper: 0.1).
    attn_dropout: dropout on attention probabilities; None means `dropout`. 0 lets PyTorch use
        its fused CPU attention kernel (a measured speed option, documented in the README).
    cross_attention: add a cross-attention sub-layer to every block (the Standard baseline).
    kv_heads: key/value heads of self-attention; None means `heads` (standard multi-head, the
        paper). Fewer (grouped-query; 1 is multi-query attention) shrink the KV cache that
        imagination reads at every token, which is what bounds its speed on a CPU.
    """

    hidden: int = 256
    layers: int = 4
    heads: int = 4
    dropout: float = 0.1
    attn_dropout: float | None = None
    cross_attention: bool = False
    kv_heads: int | None = None

    def __post_init__(self) -> None:
        if self.hidden % self.heads:
            raise ValueError(f"hidden ({self.hidden}) must be divisible by heads ({self.heads})")
        if self.heads % self.num_kv_heads:
            raise ValueError(f"heads ({self.heads}) must be divisible by kv_heads ({self.kv_heads})")

    @property
    def num_kv_heads(self) -> int:
        return self.heads if self.kv_heads is None else self.kv_heads

    @property
    def attention_dropout(self) -> float:
        return self.dropout if self.attn_dropout is None else self.attn_dropout


class KVCache:
    """Keys and values of every layer for B sequences of up to `max_len` tokens."""

    def __init__(self, layers: int, batch: int, heads: int, head_dim: int, max_len: int, dtype, device) -> None:
        shape = (layers, batch, heads, max_len, head_dim)
        self.k = torch.zeros(shape, dtype=dtype, device=device)
        self.v = torch.zeros(shape, dtype=dtype, device=device)
        self.length = 0
        self.max_len = max_len
        self.memory_kv: list[tuple[torch.Tensor, torch.Tensor]] | None = None  # cross-attention, per layer

    def select(self, index: torch.Tensor) -> None:
        """Keep only the sequences at `index` (e.g. drop finished trajectories)."""
        self.k = self.k[:, index]
        self.v = self.v[:, index]
        if self.memory_kv is not None:
            self.memory_kv = [(k[index], v[index]) for k, v in self.memory_kv]


class SelfAttention(nn.Module):
    def __init__(self, cfg: DecoderConfig) -> None:
        super().__init__()
        self.heads = cfg.heads
        self.kv_heads = cfg.num_kv_heads
        self.head_dim = cfg.hidden // cfg.heads
        self.scale = attention_scale(self.head_dim)
        self.qkv = nn.Linear(cfg.hidden, cfg.hidden + 2 * self.kv_heads * self.head_dim)
        self.proj = nn.Linear(cfg.hidden, cfg.hidden)
        self.attn_dropout = cfg.attention_dropout
        self.resid_dropout = nn.Dropout(cfg.dropout)

    def forward(self, x: torch.Tensor, cache: KVCache | None = None, layer: int = 0) -> torch.Tensor:
        b, n, h = x.shape
        d, kvh = self.head_dim, self.kv_heads
        q, k, v = self.qkv(x).split([h, kvh * d, kvh * d], dim=-1)
        q = q.view(b, n, self.heads, d).transpose(1, 2)  # [B, heads, n, d]
        k = k.view(b, n, kvh, d).transpose(1, 2)  # [B, kv_heads, n, d]
        v = v.view(b, n, kvh, d).transpose(1, 2)
        if cache is None:
            p = self.attn_dropout if self.training else 0.0
            y = F.scaled_dot_product_attention(q, k, v, is_causal=True, dropout_p=p, enable_gqa=kvh != self.heads)
        else:
            start = cache.length
            cache.k[layer, :, :, start : start + n] = k
            cache.v[layer, :, :, start : start + n] = v
            keys = cache.k[layer, :, :, : start + n]  # [B, kv_heads, L, d]
            values = cache.v[layer, :, :, : start + n]
            # The query heads that share a key/value head become rows of one matmul, so each
            # cached key is read once per token. Plain matmuls: for a query of a token or two
            # against a strided cache view they beat scaled_dot_product_attention on CPU.
            group = self.heads // kvh
            qg = q.reshape(b, kvh, group * n, d)
            scores = (qg @ keys.transpose(-1, -2)) * self.scale  # [B, kv_heads, group * n, L]
            if n > 1:  # new token i sees the past and the new tokens up to itself
                allowed = torch.ones(n, start + n, dtype=torch.bool, device=x.device).tril(diagonal=start)
                scores = scores.masked_fill(~allowed.repeat(group, 1), float("-inf"))
            y = (torch.softmax(scores, dim=-1) @ values).reshape(b, self.heads, n, d)
        y = y.transpose(1, 2).reshape(b, n, h)
        return self.resid_dropout(self.proj(y))


class CrossAttention(nn.Module):
    """Attention from decoder tokens to a memory (description tokens) with a padding mask."""

    def __init__(self, cfg: DecoderConfig) -> None:
        super().__init__()
        self.heads = cfg.heads
        self.q = nn.Linear(cfg.hidden, cfg.hidden)
        self.kv = nn.Linear(cfg.hidden, 2 * cfg.hidden)
        self.proj = nn.Linear(cfg.hidden, cfg.hidden)
        self.attn_dropout = cfg.attention_dropout
        self.resid_dropout = nn.Dropout(cfg.dropout)

    def memory_kv(self, memory: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        b, m, h = memory.shape
        k, v = self.kv(memory).view(b, m, 2, self.heads, h // self.heads).permute(2, 0, 3, 1, 4)
        return k, v

    def forward(
        self, x: torch.Tensor, kv: tuple[torch.Tensor, torch.Tensor], memory_mask: torch.Tensor
    ) -> torch.Tensor:
        b, n, h = x.shape
        q = self.q(x).view(b, n, self.heads, h // self.heads).transpose(1, 2)
        p = self.attn_dropout if self.training else 0.0
        y = F.scaled_dot_product_attention(q, kv[0], kv[1], attn_mask=memory_mask[:, None, None, :], dropout_p=p)
        return self.resid_dropout(self.proj(y.transpose(1, 2).reshape(b, n, h)))


class Block(nn.Module):
    def __init__(self, cfg: DecoderConfig) -> None:
        super().__init__()
        self.ln_1 = nn.LayerNorm(cfg.hidden)
        self.attn = SelfAttention(cfg)
        self.cross = CrossAttention(cfg) if cfg.cross_attention else None
        self.ln_cross = nn.LayerNorm(cfg.hidden) if cfg.cross_attention else None
        self.ln_2 = nn.LayerNorm(cfg.hidden)
        self.mlp = nn.Sequential(
            nn.Linear(cfg.hidden, 4 * cfg.hidden),
            nn.GELU(),
            nn.Linear(4 * cfg.hidden, cfg.hidden),
            nn.Dropout(cfg.dropout),
        )

    def forward(
        self,
        x: torch.Tensor,
        cache: KVCache | None = None,
        layer: int = 0,
        memory_kv: tuple[torch.Tensor, torch.Tensor] | None = None,
        memory_mask: torch.Tensor | None = None,
    ) -> torch.Tensor:
        x = x + self.attn(self.ln_1(x), cache, layer)
        if self.cross is not None:
            x = x + self.cross(self.ln_cross(x), memory_kv, memory_mask)
        return x + self.mlp(self.ln_2(x))


def init_weights(module: nn.Module) -> None:
    """The paper's init: N(0, 0.02) for Linear and Embedding weights, zero biases, LayerNorm (1, 0)."""
    if isinstance(module, (nn.Linear, nn.Embedding)):
        nn.init.normal_(module.weight, mean=0.0, std=0.02)
        if isinstance(module, nn.Linear) and module.bias is not None:
            nn.init.zeros_(module.bias)
    elif isinstance(module, nn.LayerNorm):
        nn.init.ones_(module.weight)
        nn.init.zeros_(module.bias)


def zero_init(linear: nn.Linear) -> None:
    """Start a residual contribution at zero: EMMA-LWM's and GPTHard's manual values (the
    measurement is in world/emma.py's docstring)."""
    nn.init.zeros_(linear.weight)
    nn.init.zeros_(linear.bias)


def head(hidden: int, out: int) -> nn.Sequential:
    """An output head: Linear-ReLU-Linear."""
    return nn.Sequential(nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, out))


def attention_scale(dim: int) -> float:
    return 1.0 / math.sqrt(dim)

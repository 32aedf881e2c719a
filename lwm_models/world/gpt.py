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
        its fused CPU attention kernel (faster on CPU; dropout then acts elsewhere only).
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
    """Keys and values of every layer for B sequences of up to `max_len` tokens.

    Each sequence has its own length, so sequences that started at different times can run in
    one batch (continuous batching: trajectories join and leave between steps). A call feeds the
    same number of new tokens to every sequence: `begin` says where they go, `update` writes a
    layer's keys and values there and returns what the new tokens attend to, `advance` moves on.

    The sequences are stored right-aligned: every sequence's next token goes to the same column
    (`self.end`), so a call writes one slice whatever the lengths, and sequence i holds columns
    [end - lengths[i], end). The columns before a shorter sequence's start are hidden from it by a
    bias that changes only when sequences join or leave. (Per-row write positions and a bias built
    at every call cost 15% of the world-model server's batched steps, measured with py-spy.) Keys carry
    their positions (learned absolute embeddings added at the input), so where a key is stored
    does not matter, only what each query may see.
    """

    def __init__(self, layers: int, batch: int, heads: int, head_dim: int, max_len: int, dtype, device) -> None:
        shape = (layers, batch, heads, max_len, head_dim)
        self.k = torch.zeros(shape, dtype=dtype, device=device)
        self.v = torch.zeros(shape, dtype=dtype, device=device)
        self.lengths = torch.zeros(batch, dtype=torch.long, device=device)
        self.max_len = max_len
        self.end = 0  # the column every sequence's next token goes to
        self.memory_kv: list[tuple[torch.Tensor, torch.Tensor]] | None = None  # cross-attention, per layer
        # [B, 1, 1, 1, max_len]: -inf at the columns before each sequence's start, 0 elsewhere;
        # None while every sequence starts at column 0 (they all have length `end`).
        self._pad: torch.Tensor | None = None
        self._bias: torch.Tensor | None = None  # this call's: what each new token may not see

    def __len__(self) -> int:
        return self.k.shape[1]

    def begin(self, n: int) -> torch.Tensor:
        """Prepare for n new tokens per sequence; returns their absolute positions ([n] when every
        sequence has the same length, else [B, n])."""
        if self.end + n > self.max_len:
            raise ValueError(f"the KV cache holds {self.max_len} tokens; {self.end} + {n} do not fit")
        offsets = torch.arange(n, device=self.lengths.device)
        total = self.end + n
        bias = None if self._pad is None else self._pad[..., :total]
        if n > 1:  # token i of the new ones sees the cache and the new tokens up to itself
            causal = torch.zeros(n, total, dtype=self.k.dtype)
            causal.masked_fill_(~torch.ones(n, total, dtype=torch.bool).tril(diagonal=self.end), float("-inf"))
            bias = causal if bias is None else bias + causal
        self._bias = bias
        return self.end + offsets if self._pad is None else self.lengths[:, None] + offsets

    def update(
        self, layer: int, k: torch.Tensor, v: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """Store a layer's new keys and values ([B, kv_heads, n, d]); returns all keys and values the
        new tokens may attend to ([B, kv_heads, L, d]) and the bias to add to their attention
        scores viewed as [B, kv_heads, query heads per key head, n, L] (None: they see all)."""
        n = k.shape[2]
        self.k[layer, :, :, self.end : self.end + n] = k
        self.v[layer, :, :, self.end : self.end + n] = v
        return self.k[layer, :, :, : self.end + n], self.v[layer, :, :, : self.end + n], self._bias

    def advance(self, n: int) -> None:
        self.lengths = self.lengths + n
        self.end += n
        self._bias = None

    def select(self, index: torch.Tensor) -> None:
        """Keep only the sequences at `index` (e.g. drop finished trajectories), moved left so that
        the longest starts at column 0 again."""
        self.lengths = self.lengths[index]
        first = self.end - int(self.lengths.max()) if len(self.lengths) else self.end  # none left: end 0
        self.k = _shifted(self.k[:, index], -first)
        self.v = _shifted(self.v[:, index], -first)
        self.end -= first
        if self.memory_kv is not None:
            self.memory_kv = [(k[index], v[index]) for k, v in self.memory_kv]
        self._mask_starts()

    def extend(self, other: KVCache) -> None:
        """Append the sequences of another cache of the same sizes (new trajectories joining),
        right-aligned with these."""
        end = max(self.end, other.end)  # an empty cache's end is 0 (`select` resets it)
        self.k = torch.cat([_shifted(self.k, end - self.end), _shifted(other.k, end - other.end)], dim=1)
        self.v = torch.cat([_shifted(self.v, end - self.end), _shifted(other.v, end - other.end)], dim=1)
        self.lengths = torch.cat([self.lengths, other.lengths])
        self.end = end
        self.memory_kv = None  # recomputed from the joined conditioning at the next call
        self._mask_starts()

    def _mask_starts(self) -> None:
        starts = self.end - self.lengths
        if not len(starts) or bool((starts == 0).all()):
            self._pad = None
            return
        hidden = torch.arange(self.max_len, device=starts.device)[None, :] < starts[:, None]
        pad = torch.zeros(hidden.shape, dtype=self.k.dtype, device=starts.device).masked_fill_(hidden, float("-inf"))
        self._pad = pad[:, None, None, None, :]


def _shifted(x: torch.Tensor, by: int) -> torch.Tensor:
    """Cache tensor [layers, B, heads, max_len, d] with its columns moved right by `by` (left if
    negative); columns moved in are zero."""
    if by == 0:
        return x
    out = torch.zeros_like(x)
    if by > 0:
        out[:, :, :, by:] = x[:, :, :, :-by]
    else:
        out[:, :, :, :by] = x[:, :, :, -by:]
    return out


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
            keys, values, bias = cache.update(layer, k, v)  # [B, kv_heads, L, d]
            # The query heads that share a key/value head become rows of one matmul, so each
            # cached key is read once per token. Plain matmuls: for a query of a token or two
            # against a strided cache view they beat scaled_dot_product_attention on CPU.
            group = self.heads // kvh
            qg = q.reshape(b, kvh, group * n, d)
            scores = (qg @ keys.transpose(-1, -2)) * self.scale  # [B, kv_heads, group * n, L]
            if bias is not None:  # rows of qg are (query head in group, new token)
                scores = (scores.view(b, kvh, group, n, -1) + bias).view(b, kvh, group * n, -1)
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

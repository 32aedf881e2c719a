"""The world model's decoder as one flat function for imagination: no module tree, one TorchScript
graph per call.

A decoder call of the shipped model (hidden 128, 2 layers) on one token is ~6 us of arithmetic but
cost ~730 us through the module tree: hundreds of ATen ops each dispatched from Python
(issue 32). Here the weights of every layer are plain tensors in lists and one scripted function
runs the whole call (embedding, blocks, final LayerNorm), so the per-op cost is the TorchScript
interpreter's, not Python's.

The same ops run in the same order as `WorldModel.hidden_states` with a KV cache (F.linear,
F.layer_norm, the grouped-query matmuls, softmax), so a call on the same tokens gives the same
numbers up to the rounding of matmuls of other shapes.

The cache here (`RowCache`) differs from gpt.KVCache in one way that matters for speculative
decoding (world/speculative.py): every row has its own length and a call writes each row's new
tokens at that row's own columns. Rows are stored left-aligned (row i holds columns
[0, lengths[i]), so a key's column is its position), and a query sees the columns up to its own
position: what a row wrote past its length (a rejected draft, padding) is never read and is
overwritten by its next call.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import TypeVar

import torch
import torch.nn.functional as F
from torch import nn

from ..messenger.constants import NUM_IDS
from .base import MAX_LEN, WorldModel
from .tokens import BLOCK, ID_SLOTS

T = TypeVar("T")
CAPACITY = MAX_LEN + BLOCK  # a row's last call may write up to a block of padding past MAX_LEN
SHRINK_ABOVE = 32  # a RowCache's store shrinks (to twice its rows) only when it has room for more rows than this
CHUNK_SAVING = 2048  # query-columns of attention a chunk of rows must save to be worth its ops (`_chunks`)


class RowCache:
    """Keys and values [layers, B, kv_heads, CAPACITY, d] of B rows, each of its own length.

    The B rows are the first of a larger store that grows by doubling, so rows that join
    (`extend`) are written in place and rows that leave (`select`) are moved down in place, each
    copying only the columns in use: a server admits or drops a request most steps, and copying
    every row's whole capacity then cost its worker about 0.5 ms a step of 8 rows (docs/speed.md)."""

    def __init__(self, k: torch.Tensor, v: torch.Tensor, lengths: torch.Tensor) -> None:
        self._k, self._v, self.lengths = k, v, lengths

    @property
    def k(self) -> torch.Tensor:
        return self._k[:, : len(self.lengths)]  # each layer's rows stay contiguous

    @property
    def v(self) -> torch.Tensor:
        return self._v[:, : len(self.lengths)]

    def __len__(self) -> int:
        return len(self.lengths)

    @torch.inference_mode()  # in place on tensors made under it (a step's), which autograd never sees
    def select(self, index: torch.Tensor) -> None:
        """Keep only the rows at `index`, in its order."""
        kept = len(index)
        if kept == len(self) and bool((index == torch.arange(kept)).all()):
            return
        # A row's columns past its length are never read (a call overwrites them first).
        width = int(self.lengths[index].max()) if kept else 0
        k, v = self._k[:, index, :, :width], self._v[:, index, :, :width]
        if self._k.shape[1] > SHRINK_ABOVE and 4 * kept < self._k.shape[1]:
            self._reallocate(2 * kept)  # a burst of rows has passed: give its memory back
        self._k[:, :kept, :, :width] = k
        self._v[:, :kept, :, :width] = v
        self.lengths = self.lengths[index]

    @torch.inference_mode()
    def extend(self, other: RowCache) -> None:
        """Append another cache's rows (trajectories joining between steps)."""
        old, n = len(self), len(self) + len(other)
        if n > self._k.shape[1]:
            width = int(self.lengths.max()) if old else 0
            k, v = self._k[:, :old, :, :width], self._v[:, :old, :, :width]
            self._reallocate(max(n, 2 * self._k.shape[1]))
            self._k[:, :old, :, :width] = k
            self._v[:, :old, :, :width] = v
        width = int(other.lengths.max()) if len(other) else 0
        self._k[:, old:n, :, :width] = other.k[:, :, :, :width]
        self._v[:, old:n, :, :width] = other.v[:, :, :, :width]
        self.lengths = torch.cat([self.lengths, other.lengths])

    def _reallocate(self, rows: int) -> None:
        """A new, zeroed store with room for `rows` rows (the caller copies back what it keeps)."""
        shape = list(self._k.shape)
        shape[1] = rows
        self._k, self._v = self._k.new_zeros(shape), self._v.new_zeros(shape)


class _Step(nn.Module):
    """One decoder call over n new tokens of some rows of a RowCache (scripted: see the module
    docstring). Weights are lists of per-layer tensors, not submodules."""

    def __init__(self, model: WorldModel) -> None:
        super().__init__()
        cfg = model.decoder_config
        self.hidden = cfg.hidden
        self.heads = cfg.heads
        self.kv_heads = cfg.num_kv_heads
        self.head_dim = cfg.hidden // cfg.heads
        attn = model.blocks[0].attn
        self.scale = attn.scale
        self.eps = model.ln_f.eps
        self.block = BLOCK
        self.num_ids = NUM_IDS
        self.chunk_saving = CHUNK_SAVING

        def own(t: torch.Tensor) -> torch.Tensor:
            return t.detach().clone()

        self.tok_emb = own(model.tok_emb.weight)
        self.pos_emb = own(model.pos_emb.weight)
        self.slot_offset = own(model._slot_offset)
        is_id = torch.zeros(BLOCK, dtype=torch.bool)
        is_id[torch.as_tensor(ID_SLOTS)] = True
        self.id_slot = is_id
        blocks = list(model.blocks)
        self.ln1_w = [own(b.ln_1.weight) for b in blocks]
        self.ln1_b = [own(b.ln_1.bias) for b in blocks]
        self.qkv_w = [own(b.attn.qkv.weight) for b in blocks]
        self.qkv_b = [own(b.attn.qkv.bias) for b in blocks]
        self.proj_w = [own(b.attn.proj.weight) for b in blocks]
        self.proj_b = [own(b.attn.proj.bias) for b in blocks]
        self.ln2_w = [own(b.ln_2.weight) for b in blocks]
        self.ln2_b = [own(b.ln_2.bias) for b in blocks]
        self.fc_w = [own(b.mlp[0].weight) for b in blocks]
        self.fc_b = [own(b.mlp[0].bias) for b in blocks]
        self.out_w = [own(b.mlp[2].weight) for b in blocks]
        self.out_b = [own(b.mlp[2].bias) for b in blocks]
        self.lnf_w = own(model.ln_f.weight)
        self.lnf_b = own(model.ln_f.bias)

    def forward(
        self,
        tokens: torch.Tensor,
        rows: torch.Tensor,
        lengths: torch.Tensor,
        id_table: torch.Tensor | None,
        k_cache: torch.Tensor,
        v_cache: torch.Tensor,
        count: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Final hidden states [A, n, H] of tokens [A, n] of cache rows `rows` [A] (ascending), placed at each
        row's length (`lengths`: every row's); writes their keys and values there. `count` [A]: how
        many of each row's tokens are real; the rest is padding, left out of the per-token layers
        (its hidden states are zero, its keys and values are never read)."""
        a, n = tokens.shape
        positions = lengths.index_select(0, rows)[:, None] + torch.arange(n)[None, :]
        last = positions[:, -1] if count is None else positions[:, 0] + count - 1
        width = int(last.max()) + 1  # the columns any real token sees
        h, kvh, d = self.hidden, self.kv_heads, self.head_dim
        group = self.heads // kvh
        slot = positions % self.block
        x = F.embedding(tokens + self.slot_offset[slot], self.tok_emb)
        if id_table is not None:
            # The manual's vector of each entity id, added at id tokens (WorldModel.embed).
            ids = tokens.clamp(0, self.num_ids - 1)
            add = torch.gather(id_table, 1, ids.unsqueeze(-1).expand(-1, -1, h))
            x = x + add * ((ids > 0) & self.id_slot[slot]).unsqueeze(-1).to(add.dtype)
        # Padding past a row's last position may lie past the learned positions; it is never read.
        x = x + F.embedding(positions.clamp(max=self.pos_emb.shape[0] - 1), self.pos_emb)
        # A query sees the columns up to its own position (rows are left-aligned).
        visible = torch.arange(width)[None, None, :] <= positions[:, :, None]
        bias = torch.where(visible, 0.0, float("-inf")).view(a, 1, n, 1, width)
        # The per-token layers run on the real tokens only, packed [T, H]; the attention on [A, n].
        keep: torch.Tensor | None = None
        if count is not None:
            real = (torch.arange(n)[None, :] < count[:, None]).view(-1)
            if not bool(real.all()):
                keep = real.nonzero().squeeze(1)
        x = x.view(a * n, h)
        at, owner = positions.reshape(-1), rows[:, None].expand(a, n).reshape(-1)
        if keep is not None:
            x, at, owner = x.index_select(0, keep), at.index_select(0, keep), owner.index_select(0, keep)
        # Where each new key goes in the cache viewed as [rows * kv_heads * capacity, d], in the
        # (token, kv head) order of the projection's output.
        slots = ((owner[:, None] * kvh + torch.arange(kvh)[None, :]) * k_cache.shape[3] + at[:, None]).view(-1)
        # A call's rows are often a run of consecutive cache rows (a lane's group, all of a step's
        # rows at its start): then the attention reads the cache in place, not a gathered copy.
        lo = int(rows[0]) if a > 0 else 0
        consecutive = a > 0 and int(rows[-1]) - lo + 1 == a  # rows ascend
        chunks = _chunks(last, width, n, self.chunk_saving)
        for i in range(len(self.qkv_w)):
            y = F.layer_norm(x, [h], self.ln1_w[i], self.ln1_b[i], self.eps)
            qkv = F.linear(y, self.qkv_w[i], self.qkv_b[i])
            kc, vc = k_cache[i], v_cache[i]
            kc.view(-1, d).index_copy_(0, slots, qkv[:, h : h + kvh * d].reshape(-1, d))
            vc.view(-1, d).index_copy_(0, slots, qkv[:, h + kvh * d :].reshape(-1, d))
            q = qkv[:, :h]
            if keep is not None:
                q = torch.zeros(a * n, h).index_copy_(0, keep, q)
            # Rows of one matmul: a kv head's query heads for each token, (token, head) within a
            # row; with one kv head that is the projection's own layout.
            qg = q.reshape(a, n, kvh, group, d).permute(0, 2, 1, 3, 4).reshape(a, kvh, n * group, d)
            if len(chunks) == 1:
                att = self._attend(qg, kc, vc, rows, lo, consecutive, bias, 0, a, width)
            else:
                parts: list[torch.Tensor] = []
                for chunk in chunks:
                    parts.append(self._attend(qg, kc, vc, rows, lo, consecutive, bias, chunk[0], chunk[1], chunk[2]))
                att = torch.cat(parts, 0)
            att = att.view(a, kvh, n, group, d).permute(0, 2, 1, 3, 4).reshape(a * n, h)
            if keep is not None:
                att = att.index_select(0, keep)
            x = x + F.linear(att, self.proj_w[i], self.proj_b[i])
            y = F.layer_norm(x, [h], self.ln2_w[i], self.ln2_b[i], self.eps)
            x = x + F.linear(F.gelu(F.linear(y, self.fc_w[i], self.fc_b[i])), self.out_w[i], self.out_b[i])
        x = F.layer_norm(x, [h], self.lnf_w, self.lnf_b, self.eps)
        if keep is not None:
            x = torch.zeros(a * n, h).index_copy_(0, keep, x)
        return x.view(a, n, h)

    def _attend(
        self,
        qg: torch.Tensor,
        kc: torch.Tensor,
        vc: torch.Tensor,
        rows: torch.Tensor,
        lo: int,
        consecutive: bool,
        bias: torch.Tensor,
        r0: int,
        r1: int,
        width: int,
    ) -> torch.Tensor:
        """The attention [r1 - r0, kv_heads, n * group, d] of the call's rows r0..r1-1 (queries qg [A,
        kv_heads, n * group, d]) over their first `width` columns of one layer's cache."""
        b, kvh, m, d = r1 - r0, qg.shape[1], qg.shape[2], qg.shape[3]
        if consecutive:
            keys, values = kc[lo + r0 : lo + r1, :, :width], vc[lo + r0 : lo + r1, :, :width]
        else:
            mine = rows[r0:r1]
            keys, values = kc[:, :, :width].index_select(0, mine), vc[:, :, :width].index_select(0, mine)
        # Batched over (row, kv head) as 3-d matmuls, the scale and the mask applied in place:
        # the same numbers as 4-d matmuls, in less time (docs/speed.md has the gain).
        keys, values = keys.reshape(b * kvh, width, d), values.reshape(b * kvh, width, d)
        scores = torch.bmm(qg[r0:r1].reshape(b * kvh, m, d), keys.transpose(1, 2))
        n = bias.shape[2]
        scores = scores.mul_(self.scale).view(b, kvh, n, m // n, width).add_(bias[r0:r1, :, :, :, :width])
        att = torch.bmm(torch.softmax(scores.view(b * kvh, m, width), dim=-1), values)
        return att.view(b, kvh, m, d)


def _chunks(last: torch.Tensor, width: int, n: int, saving: int) -> list[tuple[int, int, int]]:
    """The call's rows as consecutive chunks (first row, end, columns) whose attention runs at each
    chunk's own width. Rows of very different lengths share a call where requests join a running
    batch (a server's rows were 1.9x the columns they needed, on average); there the rows are in
    order of age, so consecutive rows need similar widths. A chunk costs a few ops per layer, so
    rows are cut in 2 or 4 only where that saves `saving` query-columns a chunk (`last`: each
    row's last position, n queries a row; TorchScript reads no module constants)."""
    a = last.shape[0]
    one = [(0, a, width)]
    # Two chunks save at most the later half's rows times the spread of widths; four, less per chunk.
    if a < 2 or (width - int(last.min()) - 1) * ((a + 1) // 2) * n < saving:
        return one
    need: list[int] = (last + 1).tolist()
    best, best_cost = one, a * width * n
    for k in [2, 4]:
        if a < k:
            break
        chunks: list[tuple[int, int, int]] = []
        cost = (k - 1) * saving
        for i in range(k):
            r0, r1 = a * i // k, a * (i + 1) // k
            w = max(need[r0:r1])
            chunks.append((r0, r1, w))
            cost += (r1 - r0) * w * n
        if cost < best_cost:
            best, best_cost = chunks, cost
    return best


class FlatDecoder:
    """A WorldModel's decoder for imagination, as of the weights it was built from (`for_model`
    rebuilds it when they change). Kinds with cross-attention (Standard) are not supported."""

    def __init__(self, model: WorldModel, script: bool = True) -> None:
        if not supports(model):
            raise ValueError(f"the flat decoder does not support a {model.kind} model (cross-attention)")
        cfg = model.decoder_config
        self.layers, self.kv_heads, self.head_dim = cfg.layers, cfg.num_kv_heads, cfg.hidden // cfg.heads
        self.dtype = next(model.parameters()).dtype
        with torch.no_grad():
            step = _Step(model).eval()
            # Scripting removes Python from the per-op path; freezing folds the weights into the
            # graph as constants. (Measured on the shipped model in benchmarks/imagination.py.)
            self._step = scripted(step, freeze=True) if script else step
        self.obs_head, self.reward_head, self.done_head = model.obs_head, model.reward_head, model.done_head

    @staticmethod
    def for_model(model: WorldModel) -> FlatDecoder:
        """The model's flat decoder, built once per version of its weights."""
        return per_weights(model, "flat_decoder", FlatDecoder)

    def new_cache(self, batch: int) -> RowCache:
        shape = (self.layers, batch, self.kv_heads, CAPACITY, self.head_dim)
        z = torch.zeros(shape, dtype=self.dtype)
        return RowCache(z, z.clone(), torch.zeros(batch, dtype=torch.long))

    def __call__(
        self, tokens: torch.Tensor, cache: RowCache, id_table: torch.Tensor | None, rows: torch.Tensor | None = None
    ) -> torch.Tensor:
        """Hidden states [A, n, H] of n new tokens [A, n] for cache rows `rows` (default: all), placed
        at each row's length; the lengths are not advanced (the caller accepts what it keeps)."""
        rows = torch.arange(len(cache)) if rows is None else rows
        return self._step(tokens, rows, cache.lengths, id_table, cache.k, cache.v)


def scripted(module: nn.Module, freeze: bool = False) -> torch.jit.ScriptModule:
    """`module` under TorchScript (frozen: weights folded in as constants). TorchScript is
    deprecated in favour of torch.compile, which measured slower here at batch 16-64 and compiles
    for a minute (issue 32), so its deprecation warning is silenced."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        out = torch.jit.script(module)
        return torch.jit.freeze(out) if freeze else out


def per_weights(model: WorldModel, name: str, build: Callable[[WorldModel], T]) -> T:
    """`build(model)`, kept on the model until its weights change (an optimizer step or a load
    changes a parameter's version, so what is kept never goes stale)."""
    version = tuple((id(p), p._version) for p in model.parameters())
    kept = model.__dict__.setdefault("_per_weights", {})  # not a submodule: no state_dict entry
    if name not in kept or kept[name][0] != version:
        kept[name] = (version, build(model))
    return kept[name][1]


def supports(model: WorldModel) -> bool:
    """Whether the flat decoder can run this model (every kind but the cross-attending Standard)."""
    return not model.decoder_config.cross_attention


__all__ = ["CAPACITY", "FlatDecoder", "RowCache", "per_weights", "scripted", "supports"]

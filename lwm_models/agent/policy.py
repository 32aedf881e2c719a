"""The EMMA policy (docs/benchmarks.md, "Table 3"): it reads the manual the way EMMA-LWM does and acts on the grid.

The frozen encoder's description tokens, projected to the policy's width, are read by
`DescriptionAttention` (the module EMMA-LWM reads the manual with) with the policy's own id
embeddings as queries; what an entity's id read is painted into the entity's cell. The avatar's
cell gets the avatar's own embedding. The last 3 observations are stacked on the
channel axis, then a small convolution and an MLP give the logits of the 5 actions. It samples in
training and takes the argmax in evaluation.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from ..messenger.constants import GRID, NUM_ACTIONS, NUM_IDS
from ..world.checkpoint import CheckpointError, load_into, publish, read_config, read_weights, write_weights
from ..world.description_attention import DescriptionAttention
from ..world.frozen_text import FrozenTextEncoder
from ..world.manual import ManualBatch, text_manual

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
        self.id_emb = nn.Embedding(NUM_IDS, c.embed)
        self.reader = DescriptionAttention(c.embed, project_values=False)
        self.conv = nn.Sequential(
            nn.Conv2d(HISTORY * c.embed, c.conv, 2), nn.LeakyReLU(), nn.Conv2d(c.conv, c.conv, 2), nn.LeakyReLU()
        )
        self.mlp = nn.Sequential(
            nn.Linear(c.conv * (GRID - 2) ** 2, c.hidden), nn.LeakyReLU(), nn.Linear(c.hidden, NUM_ACTIONS)
        )

    def id_values(self, manual: ManualBatch) -> torch.Tensor:
        """[B, 17, E]: what each id token reads from the manual (computed once per manual)."""
        return self.reader(self.text_proj(manual.features), manual.mask, self.id_emb.weight)

    def entity_vectors(self, history: torch.Tensor, id_values: torch.Tensor):
        """What is painted where: vectors [B, 3 frames, 4 channels, E] (entities: what their id read
        from the manual; the avatar: its own embedding), rows and cols [B, 3, 4], present [B, 3, 4]."""
        e = self.config.embed
        h = history.long()
        ids, rows, cols = h[..., 0], h[..., 1], h[..., 2]
        vec = torch.gather(id_values[:, None].expand(-1, HISTORY, -1, -1), 2, ids[..., None].expand(-1, -1, -1, e))
        is_avatar = torch.zeros_like(ids, dtype=torch.bool)
        is_avatar[..., 3] = True
        vec = torch.where(is_avatar[..., None], self.id_emb(ids), vec)
        return vec, rows, cols, ids > 0

    def forward(self, history: torch.Tensor, id_values: torch.Tensor) -> torch.Tensor:
        """history: [B, 3, 4, 3] compact observations (oldest first); id_values: [B, 17, E].
        Returns action logits [B, 5].

        The first convolution reads a [B, 3E, 10, 10] grid that is zero but for at most 12 cells, so
        it is computed from those cells alone: an entity in frame f at (r, c) adds
        W[:, f, :, dy, dx] @ v to the output at (r - dy, c - dx). Same result as painting the grid
        and convolving (see tests), with a twentieth of the first convolution's multiply-adds
        (the training step is 2.4x faster: benchmarks/policy_speed.py)."""
        b = history.shape[0]
        vec, rows, cols, present = self.entity_vectors(history, id_values)
        conv1 = self.conv[0]
        c_out, k = conv1.out_channels, conv1.kernel_size[0]
        w = conv1.weight.view(c_out, HISTORY, self.config.embed, k, k)
        contrib = torch.einsum("bfne,cfeyx->bfnyxc", vec, w)  # [B, 3, 4, k, k, C]
        offsets = torch.arange(k)
        out_rows = rows[..., None, None] - offsets[:, None]  # [B, 3, 4, k(dy), 1]
        out_cols = cols[..., None, None] - offsets[None, :]  # [B, 3, 4, 1, k(dx)]
        out_rows, out_cols = torch.broadcast_tensors(out_rows, out_cols)
        size = GRID - k + 1
        valid = present[..., None, None] & (out_rows >= 0) & (out_rows < size) & (out_cols >= 0) & (out_cols < size)
        bi = torch.arange(b)[:, None, None, None, None].expand_as(out_rows)
        x = torch.zeros(b, size, size, c_out, dtype=contrib.dtype)
        x.index_put_((bi[valid], out_rows[valid], out_cols[valid]), contrib[valid], accumulate=True)
        x = x.permute(0, 3, 1, 2) + conv1.bias[None, :, None, None]
        return self.mlp(self.conv[1:](x).flatten(1))

    def forward_dense(self, history: torch.Tensor, id_values: torch.Tensor) -> torch.Tensor:
        """The same logits by painting the grid and convolving it (the reference for forward)."""
        b, e = history.shape[0], self.config.embed
        vec, rows, cols, present = self.entity_vectors(history, id_values)
        grid = torch.zeros(b, HISTORY, GRID, GRID, e, dtype=vec.dtype)
        bi = torch.arange(b)[:, None, None].expand_as(rows)
        fi = torch.arange(HISTORY)[None, :, None].expand_as(rows)
        grid.index_put_((bi[present], fi[present], rows[present], cols[present]), vec[present], accumulate=True)
        x = grid.permute(0, 1, 4, 2, 3).reshape(b, HISTORY * e, GRID, GRID)
        return self.mlp(self.conv(x).flatten(1))


def policy_manual(descriptions: Sequence[str], encoder: FrozenTextEncoder) -> ManualBatch:
    """A manual as the policy reads it: the frozen encoder's tokens of its three descriptions."""
    return text_manual(descriptions, encoder)


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
    with torch.inference_mode():
        logits = policy(torch.from_numpy(np.ascontiguousarray(history)), id_values)
    if sample:
        return torch.multinomial(torch.softmax(logits, -1), 1, generator=generator).squeeze(1).numpy()
    return logits.argmax(-1).numpy()


POLICY_FORMAT = "lwm-emma-policy"


def save_policy(
    policy: EmmaPolicy, directory: str | Path, meta: dict | None = None, also: Callable[[Path], None] | None = None
) -> Path:
    """Write a policy in the checkpoint format of the world models (world/checkpoint.py); `also`
    writes more files into the same directory, which appear together with the weights."""
    config = {"format": POLICY_FORMAT, "version": 2, "config": asdict(policy.config), **(meta or {})}
    state = {k: v.detach() for k, v in policy.state_dict().items()}

    def fill(d: Path) -> None:
        write_weights(d, state, config)
        if also is not None:
            also(d)

    return publish(directory, fill)


def load_policy(directory: str | Path) -> EmmaPolicy:
    config = read_config(directory, POLICY_FORMAT)
    state = read_weights(directory, config)
    try:
        policy = EmmaPolicy(PolicyConfig(**config["config"]))
    except (KeyError, TypeError) as exc:
        raise CheckpointError(f"{directory}: malformed policy config: {exc}") from None
    load_into(policy, directory, state)
    return policy.eval()

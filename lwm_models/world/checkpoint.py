"""World-model checkpoints: `model.safetensors` plus `config.json` in one directory.

config.json records the model kind and sizes, the text encoder, the data, the training steps and
seed, and the SHA-256 of the weights file, so a corrupt or truncated file is detected on load
instead of being used.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from ..errors import LwmError
from .base import WorldModel
from .registry import build_model, config_from_dict, config_to_dict

FORMAT = "lwm-world-model"
VERSION = 1


class CheckpointError(LwmError):
    """A checkpoint that is missing, corrupt, or does not match its config."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_checkpoint(
    model: WorldModel, directory: str | Path, meta: dict | None = None, dtype: torch.dtype | None = None
) -> Path:
    """Write the model's weights (optionally cast, e.g. fp16 for shipping) and config atomically."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().to(dtype or v.dtype).contiguous() for k, v in model.state_dict().items()}
    weights = directory / "model.safetensors"
    tmp = directory / "model.safetensors.tmp"
    save_file(state, str(tmp))
    os.replace(tmp, weights)
    config = {
        "format": FORMAT,
        "version": VERSION,
        "kind": model.kind,
        "config": config_to_dict(model.config),
        "dtype": str(dtype or next(model.parameters()).dtype).replace("torch.", ""),
        "parameters": sum(p.numel() for p in model.parameters()),
        "sha256": _sha256(weights),
        **(meta or {}),
    }
    tmp_cfg = directory / "config.json.tmp"
    tmp_cfg.write_text(json.dumps(config, indent=2))
    os.replace(tmp_cfg, directory / "config.json")
    return directory


def read_config(directory: str | Path) -> dict:
    directory = Path(directory)
    path = directory / "config.json"
    if not path.is_file():
        raise CheckpointError(f"{directory} is not a checkpoint: no config.json")
    try:
        config = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path} is not valid JSON: {exc}") from None
    if config.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not an {FORMAT} config (format={config.get('format')!r})")
    return config


def load_checkpoint(directory: str | Path, kind: str | None = None) -> tuple[WorldModel, dict]:
    """Load a checkpoint as a float32 model in eval mode; checks kind, hash and tensor shapes."""
    directory = Path(directory)
    config = read_config(directory)
    if kind is not None and config.get("kind") != kind:
        raise CheckpointError(f"{directory} holds a {config.get('kind')!r} model, expected {kind!r}")
    weights = directory / "model.safetensors"
    if not weights.is_file():
        raise CheckpointError(f"{directory}: model.safetensors is missing")
    if config.get("sha256") and _sha256(weights) != config["sha256"]:
        raise CheckpointError(f"{weights} does not match the hash in config.json: corrupt or truncated")
    try:
        model = build_model(config["kind"], config_from_dict(config["config"]))
    except (KeyError, ValueError) as exc:
        raise CheckpointError(f"{directory}: {exc}") from None
    try:
        state = load_file(str(weights))
    except Exception as exc:  # safetensors raises its own error types for bad headers
        raise CheckpointError(f"{weights} cannot be read: {exc}") from None
    try:
        model.load_state_dict({k: v.float() for k, v in state.items()})
    except RuntimeError as exc:
        raise CheckpointError(f"{weights} does not fit its config: {str(exc).splitlines()[0]}") from None
    return model.eval(), config

"""Checkpoints, one format for every trained network (world models and policies): a directory with
`model.safetensors` and `config.json`.

config.json records what the network is (`format`: lwm-world-model or lwm-emma-policy, its kind
and sizes), how it was trained, and the SHA-256 of the weights file, so a corrupt or truncated
file is detected on load instead of being used. A directory is built beside its place and swapped
in whole (`publish`), so a reader never finds the weights of one save with the config of another.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import torch
from safetensors.torch import load_file, save_file

from ..errors import LwmError
from .base import WorldModel
from .manual_reading import ANCHORS_FILE, CALIBRATION_FILE, Calibration, load_anchors
from .registry import build_model, config_from_dict, config_to_dict

FORMAT = "lwm-world-model"
VERSION = 1
WEIGHTS = "model.safetensors"


class CheckpointError(LwmError):
    """A checkpoint that is missing, corrupt, or does not match its config."""


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def recover(directory: str | Path) -> None:
    """Finish a `publish` that a killed process left half done."""
    directory = Path(directory)
    old, new = directory.with_name(directory.name + ".old"), directory.with_name(directory.name + ".new")
    if not directory.exists() and old.is_dir():
        os.replace(old, directory)
    for leftover in (old, new):
        if leftover.exists():
            shutil.rmtree(leftover)


def publish(directory: str | Path, fill: Callable[[Path], None]) -> Path:
    """Build a directory with `fill(path)` beside `directory`, then swap it in."""
    directory = Path(directory)
    recover(directory)
    new, old = directory.with_name(directory.name + ".new"), directory.with_name(directory.name + ".old")
    new.mkdir(parents=True)
    fill(new)
    if directory.exists():
        os.replace(directory, old)
    os.replace(new, directory)
    if old.exists():
        shutil.rmtree(old)
    return directory


def write_weights(directory: Path, state: dict[str, torch.Tensor], config: dict) -> None:
    """The weights file and a config.json that carries its hash, into a directory being built."""
    save_file({k: v.contiguous() for k, v in state.items()}, str(directory / WEIGHTS))
    config = {**config, "sha256": _sha256(directory / WEIGHTS)}
    (directory / "config.json").write_text(json.dumps(config, indent=2))


def read_config(directory: str | Path, fmt: str = FORMAT) -> dict:
    directory = Path(directory)
    path = directory / "config.json"
    if not path.is_file():
        raise CheckpointError(f"{directory} is not a checkpoint: no config.json")
    try:
        config = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise CheckpointError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(config, dict) or config.get("format") != fmt:
        found = config.get("format") if isinstance(config, dict) else None
        raise CheckpointError(f"{path}: not an {fmt} config (format={found!r})")
    return config


def read_weights(directory: str | Path, config: dict) -> dict[str, torch.Tensor]:
    """The weights of a checkpoint as float32, after checking them against the config's hash."""
    weights = Path(directory) / WEIGHTS
    if not weights.is_file():
        raise CheckpointError(f"{directory}: {WEIGHTS} is missing")
    if _sha256(weights) != config.get("sha256"):
        raise CheckpointError(f"{weights} does not match the hash in config.json: corrupt or truncated")
    try:
        return {k: v.float() for k, v in load_file(str(weights)).items()}
    except Exception as exc:  # safetensors raises its own error types for bad headers
        raise CheckpointError(f"{weights} cannot be read: {exc}") from None


def load_into(module: torch.nn.Module, directory: str | Path, state: dict[str, torch.Tensor]) -> None:
    try:
        module.load_state_dict(state)
    except RuntimeError as exc:
        raise CheckpointError(f"{directory}: {WEIGHTS} does not fit its config: {str(exc).splitlines()[0]}") from None


def save_checkpoint(
    model: WorldModel, directory: str | Path, meta: dict | None = None, dtype: torch.dtype | None = None
) -> Path:
    """Write the model's weights (optionally cast, e.g. fp16 for shipping) and config."""
    return publish(directory, lambda d: write_checkpoint(model, d, meta, dtype))


def write_checkpoint(
    model: WorldModel, directory: Path, meta: dict | None = None, dtype: torch.dtype | None = None
) -> None:
    """A world model's checkpoint files, into a directory being built (see `publish`)."""
    state = {k: v.detach().to(dtype or v.dtype) for k, v in model.state_dict().items()}
    config = {
        "format": FORMAT,
        "version": VERSION,
        "kind": model.kind,
        "config": config_to_dict(model.config),
        "dtype": str(dtype or next(model.parameters()).dtype).replace("torch.", ""),
        "parameters": sum(p.numel() for p in model.parameters()),
        **(meta or {}),
    }
    write_weights(directory, state, config)


def load_checkpoint(directory: str | Path, kind: str | None = None) -> tuple[WorldModel, dict]:
    """Load a checkpoint as a float32 model in eval mode; checks kind, hash and tensor shapes."""
    directory = Path(directory)
    config = read_config(directory)
    if kind is not None and config.get("kind") != kind:
        raise CheckpointError(f"{directory} holds a {config.get('kind')!r} model, expected {kind!r}")
    state = read_weights(directory, config)
    try:
        model = build_model(config["kind"], config_from_dict(config["config"]))
    except (KeyError, ValueError) as exc:
        raise CheckpointError(f"{directory}: {exc}") from None
    load_into(model, directory, state)
    # A hedged EMMA-LWM reads with the rule it was measured with: "mixture" (every reading the words
    # allow) or "mean" (the mean prototype of them, the rule before; emma-lwm-practised).
    if "hedged_reading" in config and hasattr(model, "mixture"):
        model.mixture = config["hedged_reading"].get("rule", "mixture") == "mixture"
        model.ground = bool(config["hedged_reading"].get("ground", False))  # words grounded on the board
        model.doubt = float(config["hedged_reading"].get("doubt", 0.0))  # words that may decide wrongly
        # readings of one manual at most, teacher-forced (the likeliest by prior)
        model.max_readings = int(config["hedged_reading"].get("max_readings", model.max_readings))
        # of them, those predicting past the first steps (the likeliest then; 0: all)
        model.keep_readings = int(config["hedged_reading"].get("keep_readings", model.keep_readings))
    reading = [(directory / name).is_file() for name in (CALIBRATION_FILE, ANCHORS_FILE)]
    if hasattr(model, "reading_calibration") and all(reading):
        # The manual's reading (world/manual_reading.py): its calibration and its anchors, together.
        model.reading_calibration = Calibration.load(directory / CALIBRATION_FILE)
        model.anchor_keys, model.anchor_values = load_anchors(directory / ANCHORS_FILE)
    elif any(reading):
        raise CheckpointError(
            f"{directory} holds half of a reading: {CALIBRATION_FILE} and {ANCHORS_FILE} go together "
            "(scripts/fit_reading.py writes both)"
        )
    return model.eval(), config

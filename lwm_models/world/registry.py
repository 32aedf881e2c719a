"""Model kinds and size presets, by name."""

from __future__ import annotations

from dataclasses import asdict

from .base import WorldModel
from .description_encoder import TextConfig
from .emma import EmmaConfig, EmmaLWM, ObservationalLWM
from .gpt import DecoderConfig
from .gpthard import GPTHardLWM
from .oracle import OracleParseLWM
from .standard import StandardLWM

KINDS: dict[str, type[WorldModel]] = {
    "emma": EmmaLWM,
    "observational": ObservationalLWM,
    "standard": StandardLWM,
    "gpthard": GPTHardLWM,
    "oracle": OracleParseLWM,
}
NEEDS_TEXT = {"emma": True, "observational": False, "standard": True, "gpthard": True, "oracle": False}

PRESETS: dict[str, EmmaConfig] = {
    # The paper's configuration.
    "paper": EmmaConfig(DecoderConfig(hidden=256, layers=4, heads=4), TextConfig(layers=4)),
    # Sized for CPU training and for imagining 64 trajectories in about a second on 2 cores.
    "small": EmmaConfig(
        DecoderConfig(hidden=128, layers=2, heads=4, kv_heads=1, attn_dropout=0.0), TextConfig(layers=2)
    ),
    # For tests.
    "tiny": EmmaConfig(DecoderConfig(hidden=32, layers=1, heads=2), TextConfig(layers=1, heads=2)),
}


def config_to_dict(config: EmmaConfig) -> dict:
    return asdict(config)


def config_from_dict(data: dict) -> EmmaConfig:
    try:
        return EmmaConfig(DecoderConfig(**data["decoder"]), TextConfig(**data["text"]))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"malformed model config: {exc}") from None


def build_model(kind: str, config: EmmaConfig) -> WorldModel:
    if kind not in KINDS:
        raise ValueError(f"unknown model kind {kind!r}; known: {list(KINDS)}")
    return KINDS[kind](config)

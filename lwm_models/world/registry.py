"""Model kinds and size presets, by name."""

from __future__ import annotations

from dataclasses import asdict

from ..errors import LwmError
from .base import WorldModel, WorldModelConfig
from .description_encoder import TextConfig
from .emma import EmmaLWM, ObservationalLWM
from .gpt import DecoderConfig
from .gpthard import GPTHardLWM
from .hedged_gpthard import HedgedGPTHardLWM
from .hedged_reading import HedgedEmmaLWM
from .oracle import OracleParseLWM
from .standard import StandardLWM

KINDS: dict[str, type[WorldModel]] = {
    cls.kind: cls
    for cls in (EmmaLWM, HedgedEmmaLWM, ObservationalLWM, StandardLWM, GPTHardLWM, HedgedGPTHardLWM, OracleParseLWM)
}

PRESETS: dict[str, WorldModelConfig] = {
    # The paper's configuration.
    "paper": WorldModelConfig(DecoderConfig(hidden=256, layers=4, heads=4), TextConfig(layers=4)),
    # Sized for CPU training and for imagining 64 trajectories in about a second on 2 cores.
    "small": WorldModelConfig(
        DecoderConfig(hidden=128, layers=2, heads=4, kv_heads=1, attn_dropout=0.0), TextConfig(layers=2)
    ),
    # For tests.
    "tiny": WorldModelConfig(DecoderConfig(hidden=32, layers=1, heads=2), TextConfig(layers=1, heads=2)),
}


def config_to_dict(config: WorldModelConfig) -> dict:
    return asdict(config)


def config_from_dict(data: dict) -> WorldModelConfig:
    try:
        return WorldModelConfig(DecoderConfig(**data["decoder"]), TextConfig(**data["text"]))
    except (KeyError, TypeError) as exc:
        raise ValueError(f"malformed model config: {exc}") from None


class UnknownKind(LwmError, ValueError):
    """A model kind that does not exist."""


def model_class(kind: str) -> type[WorldModel]:
    """The class of a model kind, by its name."""
    if kind not in KINDS:
        raise UnknownKind(f"unknown model kind {kind!r}; known: {', '.join(KINDS)}")
    return KINDS[kind]


def build_model(kind: str, config: WorldModelConfig) -> WorldModel:
    return model_class(kind)(config)

"""The checkpoints shipped inside the package, in one catalogue: where each lives, which world
model kind it is, what tables call it, the recipe it was trained with (configs/NAME.json, a
`lwm train` or `lwm agent bc` command), and what the project uses it for."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..errors import LwmError

CHECKPOINT_DIR = Path(__file__).resolve().parent.parent / "checkpoints"


@dataclass(frozen=True)
class ShippedModel:
    key: str  # how commands, records and tables name it (`lwm agent table3 --models KEY=...`)
    directory: str  # under lwm_models/checkpoints/; its recipe is configs/<directory>.json
    kind: str  # world model kind (lwm_models/world/registry.py), or "policy"
    title: str  # as the results tables name it
    table3: bool = False  # one of the world models Table 3 compares by default

    @property
    def path(self) -> Path:
        return CHECKPOINT_DIR / self.directory

    @property
    def present(self) -> bool:
        return (self.path / "config.json").is_file()


# World models in the paper's order. OracleParse reads the game's true parse, not a manual, so the
# world-model server (which is given only descriptions) does not serve it; it is Table 3's reference.
WORLD_MODELS = (
    ShippedModel("observational", "observational", "observational", "Observational", table3=True),
    ShippedModel("standard", "standard", "standard", "Standard"),
    ShippedModel("gpthard", "gpthard", "gpthard", "GPTHard"),
    ShippedModel("gpthard-hedged", "gpthard-hedged", "gpthard-hedged", "GPTHard, hedged"),
    ShippedModel("emma", "emma-lwm", "emma", "EMMA-LWM", table3=True),
    ShippedModel("emma-freeform", "emma-lwm-freeform", "emma", "EMMA-LWM free-form"),
    ShippedModel("emma-reader", "emma-lwm-reader", "emma", "EMMA-LWM, reader tuned"),
    ShippedModel("emma-hedged", "emma-lwm-hedged", "emma-hedged", "EMMA-LWM, reader tuned, hedged"),
    ShippedModel("emma-practised", "emma-lwm-practised", "emma-hedged", "EMMA-LWM, hedged, practised"),
    ShippedModel("oracle", "oracle", "oracle", "OracleParse", table3=True),
)
POLICY = ShippedModel("policy-bc", "policy-bc", "policy", "warm-start policy")
"""The agent's warm-start policy (behaviour cloning on the training games)."""

SYSTEM_WORLD_MODEL = "emma-hedged"
"""The world model the system serves unless told otherwise (the world-model server, `lwm imagine`):
EMMA-LWM with its reader tuned for other words than the dataset's, reading with hedges: where the
words of a description and the model's own reading disagree, it imagines every possibility the
words leave open, and says which field was unclear (docs/language.md, "Reading with hedges"). Its
decoder is EMMA-LWM's, bit for bit; the paper's tables are EMMA-LWM's."""

SHIPPED = {m.key: m.path for m in WORLD_MODELS}
SHIPPED_POLICY = POLICY.path


def shipped_checkpoint(key: str = "emma") -> Path:
    """The shipped world model named `key` (see WORLD_MODELS); refused with the names there are."""
    model = next((m for m in WORLD_MODELS if m.key == key), None)
    if model is None:
        raise LwmError(f"no shipped world model {key!r}; shipped: {', '.join(m.key for m in WORLD_MODELS)}")
    if not model.present:
        raise LwmError(f"the shipped {key!r} checkpoint is missing from {CHECKPOINT_DIR}; train one with 'lwm train'")
    return model.path


def table3_defaults() -> dict[str, Path]:
    """The world models `lwm agent table3` compares when given none: those of the paper's Table 3
    that are shipped."""
    return {m.key: m.path for m in WORLD_MODELS if m.table3 and m.present}

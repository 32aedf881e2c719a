"""Where the shipped checkpoints live inside the package."""

from __future__ import annotations

from pathlib import Path

from ..errors import LwmError

CHECKPOINT_DIR = Path(__file__).resolve().parent.parent / "checkpoints"
SHIPPED = {"emma": CHECKPOINT_DIR / "emma-lwm", "observational": CHECKPOINT_DIR / "observational"}
SHIPPED_ORACLE = CHECKPOINT_DIR / "oracle"
"""OracleParse, Table 3's reference: it reads the game's true parse, not a manual, so the simulator
(which is given only descriptions) does not serve it."""
SHIPPED_POLICY = CHECKPOINT_DIR / "policy-bc"
"""The agent's warm-start policy (behaviour cloning on the training games), if shipped."""


def shipped_checkpoint(kind: str = "emma") -> Path:
    path = SHIPPED.get(kind)
    if path is None or not (path / "config.json").is_file():
        raise LwmError(f"no shipped {kind!r} checkpoint in {CHECKPOINT_DIR}; train one with 'lwm train'")
    return path

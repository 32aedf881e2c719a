"""The LWM simulator: a world model with a current manual, answering imagine requests.

This is the ROS-free engine behind the simulator node: it holds the manual (replaced by language
feedback, each replacement a new version) and turns an imagine request into imagined trajectories.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from .. import messages
from ..errors import LwmError
from .checkpoint import load_checkpoint
from .frozen_text import FrozenTextEncoder
from .imagine import imagine
from .manual import manual_batch
from .registry import NEEDS_TEXT
from .shipped import shipped_checkpoint


class Simulator:
    def __init__(self, checkpoint: str | Path | None = None, encoder: FrozenTextEncoder | None = None) -> None:
        self.checkpoint = Path(checkpoint) if checkpoint else shipped_checkpoint("emma")
        self.model, self.config = load_checkpoint(self.checkpoint)
        self.kind = self.config["kind"]
        if self.kind in ("oracle",):
            raise LwmError("the simulator serves models that read text manuals; OracleParse needs true parses")
        self.encoder = encoder if encoder is not None else (FrozenTextEncoder() if NEEDS_TEXT[self.kind] else None)
        self.manual: list[str] | None = None
        self.manual_version = 0
        self.manual_source = ""
        self._batch = None

    @property
    def model_name(self) -> str:
        return f"{self.kind} ({self.config.get('preset', '?')}, {self.config.get('steps', '?')} steps)"

    def set_manual(self, descriptions: list[str], source: str = "") -> int:
        """Replace the manual; returns its new version. A rejected manual changes nothing."""
        batch = manual_batch(self.kind, descriptions, self.encoder)
        self.manual, self._batch = list(descriptions), batch
        self.manual_version += 1
        self.manual_source = source
        return self.manual_version

    def status(self) -> dict:
        out = {
            "node": "lwm_simulator",
            "ready": True,
            "model": self.model_name,
            "checkpoint": str(self.checkpoint),
            "manual_version": self.manual_version,
            "manual_source": self.manual_source,
        }
        if self.manual:
            out["manual"] = self.manual
        return out

    def imagine(self, request: dict) -> dict:
        """An imagine response for a validated imagine request."""
        began = time.perf_counter()
        if "manual" in request:
            batch, manual = manual_batch(self.kind, request["manual"], self.encoder), request["manual"]
        elif self._batch is not None:
            batch, manual = self._batch, self.manual
        else:
            raise LwmError("no manual yet: publish one on /feedback/manual or put one in the request")
        first = np.asarray(request["observation"], dtype=np.uint8)
        max_steps = int(request.get("max_steps", 32))
        seed = int(request.get("seed", 0))
        if "actions" in request:
            seqs = request["actions"]
            n = len(seqs)
            actions = np.full((n, max_steps), 4, dtype=np.int64)
            for i, seq in enumerate(seqs):
                actions[i, : min(len(seq), max_steps)] = seq[:max_steps]
        else:
            n = int(request.get("n", 1))
            actions = np.random.default_rng(seed).integers(5, size=(n, max_steps))
        im = imagine(self.model, batch, first, n=n, actions=actions, max_steps=max_steps, seed=seed)
        return {
            "ok": True,
            "model": self.model_name,
            "manual_version": self.manual_version if "manual" not in request else 0,
            "manual": list(manual),
            "trajectories": im.to_json(),
            "seconds": round(time.perf_counter() - began, 4),
        }


def error_response(error: Exception) -> dict:
    return {"ok": False, "error": str(error)}


__all__ = ["Simulator", "error_response", "messages"]

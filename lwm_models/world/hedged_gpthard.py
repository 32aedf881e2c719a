"""GPTHard reading with hedges: the treatment of world/hedged_reading.py for a model whose
descriptions are routed to entities by their words rather than by attention.

GPTHard adds each description's value to the entity its words name. A hedged GPTHard reads a
description as EMMA-LWM hedged does (`HedgedReading`): where the words leave a field open, or
where GPTHard's value is not near the prototype of what they say, every triple the words allow is a
reading, and the world model is their mixture. Its "key", what decides which entity reads a
value, is the routing itself: one-hot over the ids (`routing_keys`), of the words' identity for its
own reading and of the triple's for a prototype, so a reading's distance to a prototype of another
entity is large and the routing of a prototype reading is its triple's identity. Where the words
name no entity, each allowed triple routes the value to its own identity, so an unnamed
description is hedged over the entities too, which plain GPTHard drops.

No weight changes: a checkpoint is GPTHard's plus the prototypes (the mean value GPTHard reads
from the project's generated descriptions of each triple; scripts/hedged_checkpoint.py). Its
reading never stands by nearness alone (stand distance 0): on the stress set's dev part, letting it
stand within EMMA-LWM's distance (the median of the dataset's training text) made six of the seven
styles worse (docs/language.md).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from ..messenger.constants import NUM_IDS
from .base import ManualBatch, WorldModelConfig
from .frozen_text import FrozenTextEncoder
from .gpthard import GPTHardLWM
from .hedged_reading import HedgedReading, Readings, code_fields, words_code


def routing_keys(identity_ids: torch.Tensor) -> torch.Tensor:
    """[..., 17]: the one-hot routing of each description (identity id; 0, no entity: all zeros)."""
    ids = identity_ids.clamp(0, NUM_IDS - 1)
    return F.one_hot(ids, NUM_IDS).float() * (ids > 0)[..., None]


class HedgedGPTHardLWM(HedgedReading, GPTHardLWM):
    """GPTHard whose readings are checked against their words (module docstring). The words'
    identity routes its own reading; the model's entity is the words', so no other entity is kept
    (`other_identity` 0)."""

    kind = "gpthard-hedged"

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        self._init_hedging(NUM_IDS, config.decoder.hidden)
        self.other_identity = 0.0

    def routed_identity(self, text: str, encoder: FrozenTextEncoder | None = None) -> int:
        """The identity id the words name (0: none; the readings then hedge over the entities)."""
        return int(code_fields(torch.tensor(words_code(text, encoder)))[0])

    def _values(self, features: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.v_proj(self.value_pool(self.text_encoder(features, mask), mask))

    def _read(self, manual: ManualBatch) -> tuple[torch.Tensor, torch.Tensor]:
        return routing_keys(code_fields(manual.routed)[0]), self._values(manual.features, manual.mask)

    def _read_texts(self, encoder: FrozenTextEncoder, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """The routing and value [N, W] of each text alone, in chunks (the dataset's training text)."""
        encoder = encoder.keeping(self.config.text.max_tokens)
        keys, values = [], []
        for lo in range(0, len(texts), 256):
            chunk = texts[lo : lo + 256]
            features, mask = encoder.encode(chunk)
            values.append(self._values(features.float()[:, None], mask[:, None])[:, 0])
            keys.append(routing_keys(code_fields(torch.tensor([words_code(t, encoder) for t in chunk]))[0]))
        return torch.cat(keys), torch.cat(values)

    def _tables(self, r: Readings) -> torch.Tensor:
        """[R, 17, W]: each reading's values added at the id it routes them to (GPTHard's rule)."""
        ids = torch.where(r.keys.sum(-1) > 0, r.keys.argmax(-1), 0)  # [R, 3]
        table = torch.zeros(r.values.shape[0], NUM_IDS, r.values.shape[-1], dtype=r.values.dtype)
        table.scatter_add_(1, ids.unsqueeze(-1).expand_as(r.values), r.values)
        table[:, 0] = 0  # unrouted descriptions condition nothing
        return table


__all__ = ["HedgedGPTHardLWM", "routing_keys"]

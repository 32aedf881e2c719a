"""EMMA-LWM reading with hedges: a description the world model may be misreading is read as what
its words allow, not as the model's guess.

A world model conditioned on a wrong reading of a description (the plane read as the goal when
the text says it is deadly) imagines confidently wrong futures; one conditioned on "the plane, some
role" imagines the roles' mixture and loses little. Measured on NewAll test with the
reader-tuned model (docs/language.md): each description read as the mean reading of the
generator's descriptions of its true triple gives a cross-entropy of 0.083, and of its true
identity and movement with the role left open 0.123, against 0.168 for a model that reads nothing.
A wrong commitment costs far more than a hedge.

So each description is read twice:
- by the world model (its description attention's key and value), and
- by its words: the keyword parser's identity (the frozen encoder's nearest name where no keyword
  names one), movement and role. A field no keyword rule decides stays open, and so does a
  movement keyword the encoder's nearest movement phrase disagrees with ("non-moving" holds the
  keyword "moving"). The triples that agree with what the words decide are the candidates.

Each of the 108 triples has a prototype: the mean key and value the model reads from the
project's generated descriptions of it (`fit_prototypes`, stored with the weights). The model's
own reading stands when its nearest prototype is a candidate (the words and the model agree), or
when it lies within `stand_distance` of that prototype: as near as half of the dataset's training
descriptions are read (`fit_stand_distance`), i.e. text the model reads in its own language.
Otherwise the reading becomes the mean prototype of the candidates: what the words say, hedged
over what they leave open. (The rule was chosen among soft and hard variants by cross-entropy on
the three dev splits with the dataset's descriptions; docs/language.md has the table.)

A decoder trained only on the model's own readings imagines nonsense from a mean prototype over
the three movements (NewAll-dev: 0.338, worse than reading nothing). `practise_hedges` (`lwm train
--hedge-practice`) fine-tunes the decoder, the reader frozen, with a share of the descriptions read
as the mean prototype of their words' triples, a field left open at random (`practice_codes`), so
that it learns to imagine from a hedge (checkpoint `emma-lwm-practised`; docs/language.md).

The words travel with the manual as `ManualBatch.routed`: one int per description (`words_code`),
so datasets and the world-model server fill it as they fill GPTHard's routing.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import torch

from ..messenger.constants import ALL_TRIPLES, IDENTITIES, MOVEMENTS, NUM_IDS, ROLES
from ..text.parser import nearest_value, parse_identity, parse_movement, parse_role
from .base import Conditioning, WorldModelConfig
from .emma import EmmaLWM
from .frozen_text import FrozenTextEncoder
from .manual import ManualBatch

PROTOTYPE_TEXTS = 24  # generated descriptions per triple averaged into its prototype
STAND_QUANTILE = 0.5  # of the training descriptions' distances to their nearest prototype
_TRIPLE_FIELDS = torch.tensor(
    [[IDENTITIES[i], MOVEMENTS.index(m), ROLES.index(r)] for i, m, r in ALL_TRIPLES], dtype=torch.long
)  # [108, 3]: identity id, movement index, role index


NAME_TOKENS = 36  # encoder tokens the words are read with, whichever encoder is shared


@lru_cache(maxsize=1)
def _name_encoder() -> FrozenTextEncoder:
    return FrozenTextEncoder(max_tokens=NAME_TOKENS)


def words_code(text: str, encoder: FrozenTextEncoder | None = None) -> int:
    """What a description's words decide, as one int: identity id * 16 + (movement index + 1) * 4
    + (role index + 1); 0 marks a field left open (the identity is open only when no name is
    near). A movement keyword counts only where the encoder's nearest movement phrase agrees
    ("non-moving" holds the keyword "moving"). `encoder`: a loaded frozen encoder to share (its
    text model, at the default length, so the answer does not depend on who asks)."""
    encoder = _name_encoder() if encoder is None else encoder.keeping(NAME_TOKENS)
    identity = parse_identity(text, encoder)
    movement, role = parse_movement(text), parse_role(text)
    if movement is not None and nearest_value(text, "movement", encoder) != movement:
        movement = None
    return (
        IDENTITIES.get(identity, 0) * 16
        + (0 if movement is None else MOVEMENTS.index(movement) + 1) * 4
        + (0 if role is None else ROLES.index(role) + 1)
    )


def candidates(codes: torch.Tensor) -> torch.Tensor:
    """[..., 108] bool: the triples that agree with each description's words (`words_code` [...])."""
    identity, movement, role = codes // 16, (codes // 4) % 4 - 1, codes % 4 - 1
    fields = _TRIPLE_FIELDS.to(codes.device)
    ok = (identity[..., None] == 0) | (identity[..., None] == fields[:, 0])
    ok &= (movement[..., None] < 0) | (movement[..., None] == fields[:, 1])
    ok &= (role[..., None] < 0) | (role[..., None] == fields[:, 2])
    return ok


def prototype_distances(
    keys: torch.Tensor, values: torch.Tensor, proto_keys: torch.Tensor, proto_values: torch.Tensor
) -> torch.Tensor:
    """[..., 108]: the distance of each reading (keys, values [..., W]) to each prototype, keys
    and values each scaled by the prototypes' spread."""
    scale_k, scale_v = proto_keys.std(), proto_values.std()
    mine = torch.cat([keys / scale_k, values / scale_v], -1)
    protos = torch.cat([proto_keys / scale_k, proto_values / scale_v], -1)  # [108, 2W]
    return torch.cdist(mine.reshape(-1, mine.shape[-1]), protos).view(*mine.shape[:-1], len(protos))


def hedge(
    keys: torch.Tensor,
    values: torch.Tensor,
    codes: torch.Tensor,
    proto_keys: torch.Tensor,
    proto_values: torch.Tensor,
    stand_distance: float = 0.0,
    force: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """keys, values [B, 3, W] as the model reads them, codes [B, 3] -> the keys and values to
    condition on, and [B, 3] bool: True where the model's reading stood (its nearest prototype
    agrees with the words, or lies within `stand_distance` of it). `force` [B, 3] bool: hedge
    these whatever the reading (practice, `practice_codes`)."""
    distances = prototype_distances(keys, values, proto_keys, proto_values)
    closest, nearest = distances.min(-1)
    allowed = candidates(codes)
    none_allowed = ~allowed.any(-1, keepdim=True)
    allowed = allowed | none_allowed  # words that fit no triple leave everything open
    stands = allowed.gather(-1, nearest[..., None]).squeeze(-1) | (closest <= stand_distance)
    if force is not None:
        stands = stands & ~force
    weights = allowed.float() / allowed.sum(-1, keepdim=True)
    hedged_k, hedged_v = weights @ proto_keys, weights @ proto_values
    keep = stands[..., None]
    return torch.where(keep, keys, hedged_k), torch.where(keep, values, hedged_v), stands


def practice_codes(codes: torch.Tensor, rate: float, open_rate: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Training inputs for the decoder: which descriptions [B, 3] to hedge (each with probability
    `rate`), and their words with the movement and the role each left open with probability
    `open_rate`, so that the decoder sees the mean prototypes a hedge gives, the truth averaged
    over what the words leave open, with its reward and movement to learn from."""
    force = torch.rand(codes.shape, device=codes.device) < rate
    movement_bits, role_bits = ((codes // 4) % 4) * 4, codes % 4
    open_movement = force & (torch.rand(codes.shape, device=codes.device) < open_rate)
    open_role = force & (torch.rand(codes.shape, device=codes.device) < open_rate)
    return codes - open_movement * movement_bits - open_role * role_bits, force


class HedgedEmmaLWM(EmmaLWM):
    """EMMA-LWM whose readings of descriptions are checked against their words (module docstring).
    Its weights are an EMMA-LWM's plus the 108 prototypes (buffers `proto_keys`, `proto_values`)."""

    kind = "emma-hedged"
    route = staticmethod(words_code)

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        h = config.decoder.hidden
        self.register_buffer("proto_keys", torch.zeros(len(ALL_TRIPLES), h))
        self.register_buffer("proto_values", torch.zeros(len(ALL_TRIPLES), h))
        # A reading this near its nearest prototype stands whatever the words say: the median such
        # distance of the dataset's training descriptions (`fit_stand_distance`).
        self.register_buffer("stand_distance", torch.zeros(()))
        self.practice_rate = 0.0  # set by practise_hedges: training only

    def practise_hedges(self, rate: float) -> None:
        """Train the decoder on hedged readings (`lwm train --hedge-practice`): in training mode a
        share `rate` of the descriptions is read as a hedge would read them (`practice_codes`).
        The reader is frozen, so that the prototypes and the stand distance, readings of this
        reader, stay true."""
        from .reader_tuning import reader_parameters  # the tuning module: only needed to train

        self.practice_rate = rate
        for p in reader_parameters(self):
            p.requires_grad_(False)

    def read_manual(self, descriptions, encoder, parse=None) -> ManualBatch:
        batch = super().read_manual(descriptions, encoder)
        batch.routed = torch.tensor([[words_code(d, encoder) for d in descriptions]])
        return batch

    def _hedged(self, manual: ManualBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The keys and values [B, 3, W] to condition on, and where the model's reading stood."""
        if manual.features is None or manual.mask is None or manual.routed is None:
            raise ValueError("a hedged EMMA-LWM needs the manual's encoded descriptions and their words")
        keys, values = self.reader.read(self.text_encoder(manual.features, manual.mask), manual.mask)
        codes, force = manual.routed, None
        if self.training and self.practice_rate > 0:
            codes, force = practice_codes(codes, self.practice_rate)
        return hedge(keys, values, codes, self.proto_keys, self.proto_values, self.stand_distance, force)

    def condition(self, manual: ManualBatch) -> Conditioning:
        keys, values, _ = self._hedged(manual)
        ids = torch.arange(NUM_IDS, device=keys.device)
        return Conditioning(id_table=self.reader.attend(keys, values, self.obs_embedding(ids)))

    @torch.no_grad()
    def unsure(self, manual: ManualBatch) -> list[dict]:
        """Per description of a batch-of-one manual: the fields ("identity", "movement", "role") its
        words leave open (`open`), and whether the world model's own reading stood (`guessed`: it
        filled them in itself) or it imagines a mixture of what the words allow."""
        _, _, stands = self._hedged(manual)
        out = []
        for code, stood in zip(manual.routed[0].tolist(), stands[0].tolist()):
            decided = (code // 16 > 0, (code // 4) % 4 > 0, code % 4 > 0)
            open_ = [f for f, d in zip(("identity", "movement", "role"), decided) if not d]
            out.append({"open": open_, "guessed": bool(stood)})
        return out

    @torch.no_grad()
    def fit_prototypes(self, encoder: FrozenTextEncoder, seed: int = 0) -> None:
        """Each triple's prototype: the mean key and value this model reads from up to
        `PROTOTYPE_TEXTS` of the project's generated descriptions of it (drawn with `seed`)."""
        from ..text.pools import DescriptionPools

        pools = DescriptionPools.generated()
        for t, triple in enumerate(ALL_TRIPLES):
            pool = sorted(set(pools.pool(None, triple)))
            order = np.random.default_rng([seed, t]).permutation(len(pool))[:PROTOTYPE_TEXTS]
            keys, values = self._read_texts(encoder, [pool[i] for i in order])
            self.proto_keys[t] = keys.mean(0)
            self.proto_values[t] = values.mean(0)

    @torch.no_grad()
    def fit_stand_distance(
        self, encoder: FrozenTextEncoder, texts: list[str], quantile: float = STAND_QUANTILE
    ) -> None:
        """The distance within which a reading stands whatever the words say: the `quantile` of the
        distances of `texts` (the dataset's training descriptions) to their nearest prototype. A
        description read as near a prototype as most of the training text is read is one the model
        reads in its own language."""
        keys, values = self._read_texts(encoder, texts)
        closest = prototype_distances(keys, values, self.proto_keys, self.proto_values).min(-1).values
        self.stand_distance.fill_(float(closest.quantile(quantile)))

    def _read_texts(self, encoder: FrozenTextEncoder, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """The key and value [N, W] this model reads from each text alone (reader_tuning.reading)."""
        from .reader_tuning import reading  # the tuning module: only needed when fitting

        features, mask = encoder.keeping(self.config.text.max_tokens).encode(texts)
        return reading(self, features.float(), mask)


__all__ = ["HedgedEmmaLWM", "candidates", "hedge", "practice_codes", "prototype_distances", "words_code"]

"""EMMA-LWM reading with hedges: a description the world model may be misreading is read every way
its words allow, and the world model imagines each.

A world model conditioned on a wrong reading of a description (the plane read as the goal when
the text says it is deadly) imagines confidently wrong futures, worse than reading nothing. So each
description is read twice:
- by the world model (its description attention's key and value), and
- by its words: the keyword parser's identity (the frozen encoder's nearest name where no keyword
  names one), movement and role. A field no keyword rule decides stays open. The triples that
  agree with what the words decide are the candidates.

Each of the 108 triples has a prototype: the mean key and value the model reads from the
project's generated descriptions of it (`fit_prototypes`, stored with the weights).

`readings` (the rule served): a description is read one way, the model's own, when its words decide
the movement and the role and the model's nearest prototype agrees. (A checkpoint may also let a
reading within `stand_distance` of a prototype stand where the words do not decide against it,
`fit_stand_distance`; the served ones let none stand by nearness: on the dev data, a near reading as
one of several read the dev styles better and the dataset's text as well.) Otherwise every candidate
is a reading (its prototype), the model's own reading standing for its nearest prototype with prior
`OWN_WEIGHT` where the words allow it; where the words name another entity than the model reads, the
model's entity stays a reading too (prior `OTHER_IDENTITY`). Words decide a field wrongly now and
then (a person's "it isn't the goal, it's the message" can read as the goal), so the triples one
decided field away from the words keep a small prior (`doubt`, shared among them; a checkpoint's
config sets it, `hedged_reading.doubt`) and the episode can show the truth. A manual's readings are
the combinations of its descriptions' (the likeliest `MAX_READINGS`; where an episode weighs them,
the checkpoint's `hedged_reading.max_readings`, since with the doubt a manual whose words state two
fields wrongly has its truth far down the list), and the world model is their
mixture: teacher-forced, each token's probability is the readings' weighted by their posterior given
the episode so far (`mixture_log_probs`), so a reading the episode contradicts (the plane does not
move as read) loses its weight within a few tokens; in imagination each trajectory takes one
reading, in proportion to the prior (`Conditioning.rows_for`). Measured on NewAll-dev with the
stress set's dev part (docs/language.md): a reading wrong in one field costs far more than a mixture
that holds the right one.

`hedge` is the rule before (`HedgedEmmaLWM.mixture = False`): a reading the words do not agree
with becomes the mean prototype of the candidates. The decoder imagines nonsense from a mean over
the three movements (NewAll-dev 0.338, worse than reading nothing); `practise_hedges` (`lwm train
--hedge-practice`) fine-tunes the decoder, the reader frozen, on such means (`practice_codes`;
checkpoint `emma-lwm-practised`), and training always uses `hedge`.

A model shipped with a reading calibration (world/manual_reading.py) imagines differently: read on
its board, the manual is one calibrated reading, and imagination conditions each description on
its believed triple's anchor in proportion to that reading (`on_board`, `_configured`); the
teacher-forced mixture above is unchanged.

The words travel with the manual as `ManualBatch.routed`: one int per description (`words_code`),
so datasets and the world-model server fill it as they fill GPTHard's routing.

What does not depend on how a model reads a description (the prototypes, the readings, the
mixture) is `HedgedReading`, which GPTHard reading with hedges shares (world/hedged_gpthard.py).
A model whose checkpoint config says so (`hedged_reading.ground`) first grounds the words' entities
on the board (`ground_words`: a manual describes the entities of one board), teacher-forced and in
imagination alike (`WorldModel.on_board`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np
import torch

from ..messenger.constants import ALL_TRIPLES, IDENTITIES, MOVEMENTS, NUM_IDS, ROLES
from ..text.parser import parse_identity, parse_movement, parse_role
from .base import Conditioning, WorldModel, WorldModelConfig, _targets_layout
from .emma import EmmaLWM
from .frozen_text import FrozenTextEncoder
from .manual import ManualBatch
from .tokens import BLOCK, ID_SLOTS, SLOT_DONE, SLOT_OBS, SLOT_REWARD

PROTOTYPE_TEXTS = 24  # generated descriptions per triple averaged into its prototype
STAND_QUANTILE = 0.5  # of the training descriptions' distances to their nearest prototype
_TRIPLE_FIELDS = torch.tensor(
    [[IDENTITIES[i], MOVEMENTS.index(m), ROLES.index(r)] for i, m, r in ALL_TRIPLES], dtype=torch.long
)  # [108, 3]: identity id, movement index, role index
_TRIPLE_ENTITY: list[int] = _TRIPLE_FIELDS[:, 0].tolist()  # each triple's identity id, for readings


NAME_TOKENS = 36  # encoder tokens the words are read with, whichever encoder is shared


@lru_cache(maxsize=1)
def _name_encoder() -> FrozenTextEncoder:
    return FrozenTextEncoder(max_tokens=NAME_TOKENS)


GUESSED = 512  # a words code's flag: its entity is the encoder's nearest name, no keyword's


def words_code(text: str, encoder: FrozenTextEncoder | None = None) -> int:
    """What a description's words decide, as one int: identity id * 16 + (movement index + 1) * 4
    + (role index + 1), plus `GUESSED` where no keyword names the entity and the encoder's nearest
    name does; 0 marks a field left open (the identity is open only when no name is near; read the
    fields with `code_fields`). `encoder`: a loaded frozen encoder to share (its text model, at the
    default length, so the answer does not depend on who asks)."""
    encoder = _name_encoder() if encoder is None else encoder.keeping(NAME_TOKENS)
    named = parse_identity(text)
    identity = named if named is not None else parse_identity(text, encoder)
    movement, role = parse_movement(text), parse_role(text)
    return (
        (GUESSED if named is None and identity is not None else 0)
        + IDENTITIES.get(identity, 0) * 16
        + (0 if movement is None else MOVEMENTS.index(movement) + 1) * 4
        + (0 if role is None else ROLES.index(role) + 1)
    )


def code_fields(codes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """A words code's (`words_code` [...]) identity id (0: open), movement and role index (-1:
    open)."""
    return (codes % GUESSED) // 16, (codes // 4) % 4 - 1, codes % 4 - 1


def _field_bits(codes: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The movement and the role part of words codes (`words_code`): a code less one leaves that
    field open."""
    return ((codes // 4) % 4) * 4, codes % 4


def _triples_among(among: torch.Tensor) -> torch.Tensor:
    """[..., 108] bool: the triples whose entity is among the entities `among` [..., 17] allows."""
    return among[..., _TRIPLE_FIELDS[:, 0].to(among.device)]


def candidates(codes: torch.Tensor) -> torch.Tensor:
    """[..., 108] bool: the triples that agree with each description's words (`words_code` [...])."""
    identity, movement, role = code_fields(codes)
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


def _checked(
    keys: torch.Tensor,
    values: torch.Tensor,
    codes: torch.Tensor,
    proto_keys: torch.Tensor,
    proto_values: torch.Tensor,
    among: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """Each reading checked against its words (and, `among` [B, 3, 17], the entities its board
    leaves it): its distance to its nearest prototype and which that is [B, 3], the triples the
    words allow [B, 3, 108], and whether they allow the nearest [B, 3]."""
    closest, nearest = prototype_distances(keys, values, proto_keys, proto_values).min(-1)
    allowed = candidates(codes)
    if among is not None:
        allowed &= _triples_among(among)
    allowed = allowed | ~allowed.any(-1, keepdim=True)  # words that fit no triple leave everything open
    return closest, nearest, allowed, allowed.gather(-1, nearest[..., None]).squeeze(-1)


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
    closest, nearest, allowed, agree = _checked(keys, values, codes, proto_keys, proto_values)
    stands = agree | (closest <= stand_distance)
    if force is not None:
        stands = stands & ~force
    weights = allowed.float() / allowed.sum(-1, keepdim=True)
    hedged_k, hedged_v = weights @ proto_keys, weights @ proto_values
    keep = stands[..., None]
    return torch.where(keep, keys, hedged_k), torch.where(keep, values, hedged_v), stands


OWN_WEIGHT = 0.8  # prior of the model's own reading among the readings the words allow
OTHER_IDENTITY = 0.15  # prior of the model's identity where the words name another
DOUBT = 0.05  # prior of the triples one decided field away from the words (scripts/hedged_checkpoint.py)
MAX_READINGS = 27  # readings of one manual at most (the likeliest, by prior)
MIXTURE_ROWS = 256  # reading rows per decoder pass in teacher-forced evaluation (memory)
PRUNE_STEPS = 2  # steps every reading predicts before a model with `keep_readings` keeps the likeliest


@dataclass
class Readings:
    """The readings of a batch of manuals, one row each: keys and values [R, 3, W], the manual
    (batch row) each belongs to [R], their prior log-probability [R] (normalised per manual), rows
    of a manual together and likeliest first. `alone` [B, 3]: the description is read one way only,
    the model's own reading; `own_among` [B, 3]: the model's own reading is one of several."""

    keys: torch.Tensor
    values: torch.Tensor
    owner: torch.Tensor
    log_prior: torch.Tensor
    alone: torch.Tensor
    own_among: torch.Tensor

    def likeliest(self, score: torch.Tensor, k: int) -> Readings:
        """Each manual's `k` readings of highest `score` [R], in their order (the priors are kept as
        they were: a mixture weighs its readings relative to each other)."""
        keep = torch.zeros(len(self.owner), dtype=torch.bool)
        for m in range(int(self.owner.max()) + 1):
            rows = torch.nonzero(self.owner == m).flatten()
            keep[rows[score[rows].topk(min(k, len(rows))).indices]] = True
        return replace(
            self, keys=self.keys[keep], values=self.values[keep], owner=self.owner[keep], log_prior=self.log_prior[keep]
        )


def _options(
    allow: torch.Tensor,
    own: tuple[torch.Tensor, torch.Tensor],
    nearest: int,
    with_own: bool,
    own_weight: float,
    proto_keys: torch.Tensor,
    proto_values: torch.Tensor,
) -> list[tuple[torch.Tensor, torch.Tensor, float, int]]:
    """One description's readings (key, value, prior, entity id) among the triples `allow` [108]:
    with `with_own`, the model's own reading in place of its `nearest` prototype at `own_weight`,
    the rest of the triples sharing what is left evenly; likeliest first."""
    triples = torch.nonzero(allow).flatten().tolist()
    entity = _TRIPLE_ENTITY
    if with_own:
        rest = [t for t in triples if t != nearest]
        out = [(*own, own_weight if rest else 1.0, entity[nearest])]
    else:
        rest, out = triples, []
    share = (1.0 - sum(o[2] for o in out)) / max(1, len(rest))
    return out + [(proto_keys[t], proto_values[t], share, entity[t]) for t in rest]


def _likeliest(
    per_description: list[list[tuple]], k: int, distinct: list[bool] | None = None
) -> list[tuple[tuple[int, ...], float]]:
    """The k likeliest combinations of one option per description, as (option indices, prior),
    likeliest first and ties in the order of the indices; the descriptions marked `distinct` about
    different entities (an option's entity is its fourth field). Built one description at a time,
    keeping the k likeliest partial combinations: exact (a combination among the k likeliest
    extends a partial one among the k likeliest), and it never lists the whole product (108 options
    each for three descriptions whose words name no entity would be 1.3 million)."""
    distinct = distinct or [False] * len(per_description)

    def fits(picks: tuple[int, ...]) -> bool:
        seen = [per_description[j][i][3] for j, i in enumerate(picks) if distinct[j]]
        return len(seen) == len(set(seen))

    best: list[tuple[tuple[int, ...], float]] = [((), 1.0)]
    for options in per_description:
        grown = [(picks + (i,), prior * o[2]) for picks, prior in best for i, o in enumerate(options)]
        kept = [c for c in grown if fits(c[0])]
        best = sorted(kept or grown, key=lambda c: (-c[1], c[0]))[:k]
    return best


def readings(
    keys: torch.Tensor,
    values: torch.Tensor,
    codes: torch.Tensor,
    proto_keys: torch.Tensor,
    proto_values: torch.Tensor,
    stand_distance: float = 0.0,
    own_weight: float = OWN_WEIGHT,
    max_readings: int = MAX_READINGS,
    other_identity: float = OTHER_IDENTITY,
    among: torch.Tensor | None = None,
    doubt: float = 0.0,
) -> Readings:
    """keys, values [B, 3, W] as the model reads them, codes [B, 3] -> every way each manual may be
    read, with a prior. A description is read one way, the model's own, when the words decide its
    movement and role and the model's nearest prototype agrees, or when the reading lies within
    `stand_distance` of a prototype and the words do not decide movement and role against it;
    otherwise each triple the words allow is a reading (its
    prototype), the model's own reading standing for its nearest prototype with prior `own_weight`
    where the words allow that one, the rest sharing what is left evenly. Where the words name
    another entity than the model's nearest prototype does, the readings the words allow with the
    model's entity in place of theirs join with prior `other_identity` (the rest scaled down), so
    that a misspelt or unusual name does not commit the reading to the words' guess. `among`
    [B, 3, 17] (`ground_words`): the entities each description may be about on its board; a
    reading of another entity does not stand, and the descriptions it narrows are read as about
    different entities. `doubt`: the prior of the triples one field away from what the words
    decide (their movement or their role other), the other readings scaled down, so that a field
    the words decide wrongly is not ruled out. A manual's readings are the combinations of its
    descriptions' (the likeliest `max_readings`)."""
    closest, nearest, allowed, agree = _checked(keys, values, codes, proto_keys, proto_values, among)
    decided = ((codes // 4) % 4 > 0) & (codes % 4 > 0)
    said, read = code_fields(codes)[0], _TRIPLE_FIELDS.to(codes.device)[nearest, 0]  # identity ids [B, 3]
    grounded = torch.zeros_like(decided) if among is None else ~among.all(-1)
    on_board = torch.ones_like(decided) if among is None else among.gather(-1, read[..., None]).squeeze(-1)
    # Nearness vouches for the model's language, not against words that state movement and role,
    # nor for an entity the board rules out.
    alone = (agree & decided) | ((closest <= stand_distance) & (agree | ~decided) & on_board)
    own_among = agree & ~alone
    other = (said > 0) & (said != read) & ~alone & ~grounded & (other_identity > 0)
    other_allowed = candidates(codes + (read - said) * 16)  # the words, the model's entity
    if doubt > 0:  # the words may decide a field wrongly: the triples one decided field away
        movement_bits, role_bits = _field_bits(codes)
        astray = (candidates(codes - movement_bits) | candidates(codes - role_bits)) & ~candidates(codes)
        if among is not None:
            astray &= _triples_among(among)
    ks, vs, owner, log_prior = [], [], [], []
    for b in range(keys.shape[0]):
        per_description = []
        for j in range(keys.shape[1]):
            own = (keys[b, j], values[b, j])
            near = int(nearest[b, j])
            protos = (own_weight, proto_keys, proto_values)
            if alone[b, j]:
                these = [(*own, 1.0, int(read[b, j]))]
            else:
                these = _options(allowed[b, j], own, near, bool(own_among[b, j]), *protos)
                if other[b, j]:
                    theirs = _options(other_allowed[b, j], own, near, bool(other_allowed[b, j, near]), *protos)
                    these = [(k, v, w * (1 - other_identity), e) for k, v, w, e in these]
                    these += [(k, v, w * other_identity, e) for k, v, w, e in theirs]
            if doubt > 0 and astray[b, j].any():
                these = [(k, v, w * (1 - doubt), e) for k, v, w, e in these]
                these += [(k, v, w * doubt, e) for k, v, w, e in _options(astray[b, j], own, near, False, *protos)]
            per_description.append(these)
        combos = _likeliest(per_description, max_readings, grounded[b].tolist())
        priors = torch.tensor([prior for _, prior in combos], dtype=torch.float64)
        log_prior.append(torch.log(priors / priors.sum()).float())
        for picks, _ in combos:
            ks.append(torch.stack([per_description[j][i][0] for j, i in enumerate(picks)]))
            vs.append(torch.stack([per_description[j][i][1] for j, i in enumerate(picks)]))
        owner += [b] * len(combos)
    return Readings(torch.stack(ks), torch.stack(vs), torch.tensor(owner), torch.cat(log_prior), alone, own_among)


def mixture_log_probs(
    log_probs: dict[str, torch.Tensor],
    targets: dict[str, torch.Tensor],
    positions: dict[str, torch.Tensor],
    owner: torch.Tensor,
    log_prior: torch.Tensor,
    posterior: bool = True,
) -> dict[str, torch.Tensor]:
    """The world model's predictions under its readings combined: per kind, log_probs [R, P, V] of
    each reading row, the true next tokens [R, P] (the same for the rows of one manual) and the
    positions [P] they sit at -> [B, P, V], each token's probability the mixture of the readings'
    weighted by their posterior given the true tokens before it (Bayes: prior times the
    likelihood of the episode so far). A reading that the episode contradicts loses its weight
    within a few tokens. Without `posterior`, the weights stay the prior throughout."""
    names = list(log_probs)
    pos = torch.cat([positions[k] for k in names])
    order = torch.argsort(pos)
    true = torch.cat([log_probs[k].gather(-1, targets[k][..., None]).squeeze(-1) for k in names], 1)[:, order]
    before = torch.cumsum(true, 1) - true  # log-likelihood of the tokens before each one
    back = torch.empty_like(order)
    back[order] = torch.arange(len(order))
    before = before[:, back] if posterior else torch.zeros_like(true)  # in the kinds' own order again
    manuals = int(owner.max()) + 1
    out, lo = {}, 0
    for k in names:
        p = log_probs[k].shape[1]
        weight = log_prior[:, None] + before[:, lo : lo + p]  # [R, P]
        lo += p
        mixed = []
        for m in range(manuals):
            rows = owner == m
            w = weight[rows] - torch.logsumexp(weight[rows], 0, keepdim=True)
            mixed.append(torch.logsumexp(w[..., None] + log_probs[k][rows], 0))
        out[k] = torch.stack(mixed)
    return out


def _episode_targets(tokens: torch.Tensor, lengths: torch.Tensor) -> tuple[dict, dict, dict]:
    """Per kind (obs, reward, done): the positions [P] predicting a token, the true next tokens
    [B, P] and whether each lies inside its episode [B, P]."""
    layout = _targets_layout(tokens.shape[1])
    slots = {"obs": SLOT_OBS, "reward": SLOT_REWARD, "done": SLOT_DONE}
    positions = {k: torch.as_tensor(layout[slot]) for k, slot in slots.items()}
    targets = {k: tokens[:, positions[k] + 1] for k in slots}
    valid = {k: (p + 1)[None, :] < lengths.to(tokens.device)[:, None] * BLOCK for k, p in positions.items()}
    return positions, targets, valid


def ground_words(codes: torch.Tensor, board: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The words (`words_code` [B, 3]) grounded on each manual's board (identity ids [B, K], 0 for
    none), and [B, 3, 17] bool: the entity ids each description may be about there (`readings`).

    A manual describes the entities of its board, each once. A description whose words name a
    board entity by keyword that no other keyword names is about that entity; then one whose
    encoder-guessed name is a board entity left that no other guess names. The others (words
    naming an entity off the board, none, or one another description names too) are about the
    board entities left: the one left, when one description and one entity are (the words' entity
    becomes it); else any of them, each a different one. When more descriptions than entities are
    left, their entities stay open (an entity named off the board: any)."""
    out = codes.clone()
    among = torch.ones(*codes.shape, NUM_IDS, dtype=torch.bool)
    for b in range(codes.shape[0]):
        on = list(dict.fromkeys(int(i) for i in board[b].tolist() if i > 0))
        named = code_fields(codes[b])[0].tolist()
        guessed = (codes[b] >= GUESSED).tolist()
        taken: dict[int, int] = {}  # description -> the board entity it is about
        for by_guess in (False, True):
            names = [named[j] for j in range(len(named)) if guessed[j] == by_guess and j not in taken]
            for j, entity in enumerate(named):
                free = entity in on and entity not in taken.values() and names.count(entity) == 1
                if guessed[j] == by_guess and j not in taken and free:
                    taken[j] = entity
        rest = [j for j in range(len(named)) if j not in taken]
        left = [i for i in on if i not in taken.values()]
        for j in rest:
            if len(rest) > len(left):
                out[b, j] = codes[b, j] % 16 + (named[j] * 16 if named[j] in on else 0)
                continue
            out[b, j] = codes[b, j] % 16 + (left[0] if len(left) == 1 else 0) * 16
            among[b, j] = False
            among[b, j, left] = True
    return out, among


def practice_codes(codes: torch.Tensor, rate: float, open_rate: float = 0.5) -> tuple[torch.Tensor, torch.Tensor]:
    """Training inputs for the decoder: which descriptions [B, 3] to hedge (each with probability
    `rate`), and their words with the movement and the role each left open with probability
    `open_rate`, so that the decoder sees the mean prototypes a hedge gives, the truth averaged
    over what the words leave open, with its reward and movement to learn from."""
    force = torch.rand(codes.shape, device=codes.device) < rate
    movement_bits, role_bits = _field_bits(codes)
    open_movement = force & (torch.rand(codes.shape, device=codes.device) < open_rate)
    open_role = force & (torch.rand(codes.shape, device=codes.device) < open_rate)
    return codes - open_movement * movement_bits - open_role * role_bits, force


class HedgedReading:
    """What a hedged world model does whatever reads its descriptions (mixed in before the model's
    class): the words travel as `words_code`; the 108 prototypes and the stand distance are buffers;
    a manual is read every way its words allow (`readings`) and predicted and imagined as their
    mixture. A model class gives `_read` (each description's key and value [B, 3, W] as it reads
    them), `_read_texts` (the same for N descriptions alone) and `_tables` (what each id reads
    under each reading)."""

    route = staticmethod(words_code)

    def _init_hedging(self, key_width: int, value_width: int) -> None:
        self.register_buffer("proto_keys", torch.zeros(len(ALL_TRIPLES), key_width))
        self.register_buffer("proto_values", torch.zeros(len(ALL_TRIPLES), value_width))
        # A reading this near its nearest prototype stands whatever the words say (`fit_stand_distance`).
        self.register_buffer("stand_distance", torch.zeros(()))
        # Read a manual every way its words allow and imagine each (`readings`); off (EMMA-LWM only):
        # the mean prototype of what they allow (the rule before, kept to compare).
        self.mixture = True
        self.own_weight = OWN_WEIGHT  # the prior of the model's own reading among several
        self.other_identity = OTHER_IDENTITY  # the prior of its entity where the words name another
        # The prior of the triples one decided field away from the words (`readings`); a checkpoint's
        # config sets it (`hedged_reading.doubt`).
        self.doubt = 0.0
        # The readings of one manual kept where an episode weighs them (the likeliest by prior,
        # `readings`); a checkpoint's config may set it (`hedged_reading.max_readings`). Each costs a
        # decoder pass over the episode.
        self.max_readings = MAX_READINGS
        # Where an episode weighs them: how many of a manual's readings go on predicting after its
        # first `PRUNE_STEPS` steps (the likeliest then); 0: all (`hedged_reading.keep_readings`).
        self.keep_readings = 0
        # Ground the words' entities on the board before reading (`ground_words`); a checkpoint's
        # config turns it on (`hedged_reading.ground`).
        self.ground = False
        # The calibration of the manual's reading before any step (world/manual_reading.py) and the
        # anchors imagination conditions each believed triple on ([108, W] each), shipped beside the
        # checkpoint; None: imagination reads the words' readings by their priors.
        self.reading_calibration = None
        self.anchor_keys: torch.Tensor | None = None
        self.anchor_values: torch.Tensor | None = None

    def read_manual(self, descriptions, encoder, parse=None) -> ManualBatch:
        """The manual of three descriptions as this model reads it; with a reading calibration,
        also each description's evidence for the manual's reading (`manual_reading`)."""
        batch = WorldModel.read_manual(self, descriptions, encoder)
        batch.routed = torch.tensor([[words_code(d, encoder) for d in descriptions]])
        if self.reading_calibration is not None:
            from .manual_reading import evidence_for

            batch.evidence = evidence_for(self, encoder, list(descriptions), self.reading_calibration.sentence)
        return batch

    def on_board(self, manual: ManualBatch, board: torch.Tensor) -> ManualBatch:
        """The manual read on the board: with `ground` on, its words grounded on the board
        (`ground_words`; one board row per manual, or one for all); with evidence (`read_manual`),
        also its reading (`manual_reading.read_manual`), which imagination then follows
        (`condition_on`)."""
        board = torch.as_tensor(board).long()
        if self.ground and manual.routed is not None:
            rows = board if len(board) == len(manual.routed) else board[:1].expand(len(manual.routed), -1)
            routed, among = ground_words(manual.routed, rows)
            manual = replace(manual, routed=routed, among=among)
        if manual.evidence is not None and self.reading_calibration is not None:
            from .manual_reading import read_manual

            ids = [int(i) for i in board.reshape(-1, board.shape[-1])[0] if i > 0]
            manual = replace(manual, reading=read_manual(manual.evidence, ids, self.reading_calibration, manual.facts))
        return manual

    def _read(self, manual: ManualBatch) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def _read_texts(self, encoder: FrozenTextEncoder, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        raise NotImplementedError

    def _tables(self, r: Readings) -> torch.Tensor:
        raise NotImplementedError

    def _readings(self, manual: ManualBatch, observed: bool = False) -> Readings:
        """The manual's readings (`readings`). `observed`: an episode will weigh them (teacher-forced
        predictions), so with the model's doubt and as many as its `max_readings`; else what the
        words allow, the `MAX_READINGS` likeliest (imagination, the page's status)."""
        if manual.features is None or manual.mask is None or manual.routed is None:
            raise ValueError(f"a {self.kind} model needs the manual's encoded descriptions and their words")
        keys, values = self._read(manual)
        return readings(
            keys,
            values,
            manual.routed,
            self.proto_keys,
            self.proto_values,
            float(self.stand_distance),
            self.own_weight,
            max_readings=self.max_readings if observed else MAX_READINGS,
            other_identity=self.other_identity,
            among=manual.among,
            doubt=self.doubt if observed else 0.0,
        )

    def condition(self, manual: ManualBatch) -> Conditioning:
        """One row per manual: the likeliest reading."""
        r = self._readings(manual)
        firsts = torch.searchsorted(r.owner, torch.arange(len(manual.routed)))
        return Conditioning(id_table=self._tables(r)[firsts])

    @torch.inference_mode()
    def condition_on(self, manual: ManualBatch) -> Conditioning:
        """Every reading the words allow with its prior: imagination gives each trajectory one
        (`Conditioning.rows_for`), so that n trajectories imagine each possibility in proportion.
        Not the doubted readings: imagination has no episode to weigh them by, and a person who
        reads the imagined futures (and the read-back drawn from them) should see what their words
        say; the doubt acts where an episode is observed (`predictions`). With it, 1 of 8 probes
        followed a reading the words deny and the read-back's movements fell from 98% to 89% right
        (the dataset's text, 30 NewAll test games)."""
        self.eval()
        if manual.reading is not None:
            r = self._configured(manual)
        elif not self.mixture:
            return self.condition(manual)
        else:
            r = self._readings(manual)
        return Conditioning(id_table=self._tables(r), reading_owner=r.owner, reading_log_prior=r.log_prior)

    def _configured(self, manual: ManualBatch) -> Readings:
        """The readings of a manual read on its board (`manual.reading`): its likeliest complete
        readings with their probabilities, each description conditioned on its triple's anchor
        (`manual_reading.fit_anchors`): what the model reads from the most typical description of
        that triple in the text it was trained on. A plan is then imagined in the model's own
        language whatever the person's words: the model's own reading of words unlike its training
        text imagines deaths that do not happen, even where the reading is right."""
        index = {t: k for k, t in enumerate(ALL_TRIPLES)}
        ks, vs, priors = [], [], []
        for triples, p in manual.reading.configurations():
            picks = [index[t] for t in triples]
            ks.append(self.anchor_keys[picks])
            vs.append(self.anchor_values[picks])
            priors.append(p)
        stands = torch.zeros(1, 3, dtype=torch.bool)
        log_prior = torch.log(torch.tensor(priors, dtype=torch.float64)).float()
        owner = torch.zeros(len(ks), dtype=torch.long)
        return Readings(torch.stack(ks), torch.stack(vs), owner, log_prior, stands, stands)

    def predictions(
        self, tokens: torch.Tensor, lengths: torch.Tensor, manual: ManualBatch
    ) -> dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Teacher-forced predictions; out of training, of the readings' mixture
        (`mixture_log_probs`: the log-probabilities stand for the logits). With `keep_readings`, every
        reading predicts the first `PRUNE_STEPS` steps, and only each manual's `keep_readings`
        likeliest given them (prior times likelihood) predict the rest: a reading whose movements
        the first steps contradict would cost a decoder pass over the episode for nothing. Each
        token is still predicted from the tokens before it only."""
        if self.training or not self.mixture:
            return super().predictions(tokens, lengths, manual)
        r = self._readings(self.on_board(manual, tokens[:, torch.as_tensor(ID_SLOTS)]), observed=True)
        positions, targets, valid = _episode_targets(tokens, lengths)
        cut = (1 + PRUNE_STEPS) * BLOCK
        first = None
        if self.keep_readings and tokens.shape[1] > cut and bool((r.owner.bincount() > self.keep_readings).any()):
            head = {k: p[p + 1 < cut] for k, p in positions.items()}
            n = {k: len(p) for k, p in head.items()}
            first, likelihood = self._mixture(
                tokens[:, :cut], lengths.clamp(max=cut // BLOCK), r, head,
                {k: t[:, : n[k]] for k, t in targets.items()}, {k: v[:, : n[k]] for k, v in valid.items()},
            )  # fmt: skip
            r = r.likeliest(r.log_prior + likelihood, self.keep_readings)
        mixed, _ = self._mixture(tokens, lengths, r, positions, targets, valid)
        if first is not None:
            for k, early in first.items():
                mixed[k][:, : early.shape[1]] = early
        return {k: (mixed[k], targets[k], valid[k]) for k in positions}

    @torch.no_grad()
    def prior_predictions(
        self, tokens: torch.Tensor, lengths: torch.Tensor, manual: ManualBatch
    ) -> dict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
        """Teacher-forced predictions of one episode (`predictions`' shapes) under the manual's
        reading before any step (`manual.reading`, set by `on_board`): its configurations mixed by
        their probabilities, which the episode never updates. This is what a plan imagined before
        the first real step rests on (benchmarks/before_acting.py)."""
        if manual.reading is None:
            raise ValueError("prior predictions need the manual's reading (read_manual, then on_board)")
        self.eval()
        r = self._configured(manual)
        positions, targets, valid = _episode_targets(tokens, lengths)
        mixed, _ = self._mixture(tokens, lengths, r, positions, targets, valid, posterior=False)
        return {k: (mixed[k], targets[k], valid[k]) for k in positions}

    def _mixture(
        self,
        tokens: torch.Tensor,
        lengths: torch.Tensor,
        r: Readings,
        positions: dict[str, torch.Tensor],
        targets: dict[str, torch.Tensor],
        valid: dict[str, torch.Tensor],
        posterior: bool = True,
    ) -> tuple[dict[str, torch.Tensor], torch.Tensor]:
        """The readings' mixture at `positions` (per kind, [B, P, V]), and each reading's
        log-likelihood of the true tokens there [R]."""
        tables = self._tables(r)
        parts: dict[str, list[torch.Tensor]] = {k: [] for k in positions}
        for lo in range(0, len(r.owner), MIXTURE_ROWS):
            rows = r.owner[lo : lo + MIXTURE_ROWS]
            own = WorldModel.predictions_given(
                self, tokens[rows], lengths[rows], Conditioning(id_table=tables[lo : lo + MIXTURE_ROWS])
            )
            for k, (logits, _, _) in own.items():
                parts[k].append(torch.log_softmax(logits, -1))
        log_probs = {k: torch.cat(v) for k, v in parts.items()}
        per_row = {k: t[r.owner] for k, t in targets.items()}
        likelihood = sum(
            (log_probs[k].gather(-1, per_row[k][..., None]).squeeze(-1) * valid[k][r.owner]).sum(1) for k in positions
        )
        return mixture_log_probs(log_probs, per_row, positions, r.owner, r.log_prior, posterior), likelihood

    def _stands(self, manual: ManualBatch) -> torch.Tensor:
        """[B, 3]: where the model's own reading is the only one."""
        return self._readings(manual).alone  # `alone` does not depend on the doubt

    @torch.no_grad()
    def unsure(self, manual: ManualBatch) -> list[dict]:
        """Per description of a batch-of-one manual: the fields ("identity", "movement", "role") its
        words leave open (`open`), and whether the world model's own reading stood (`guessed`: it
        filled them in itself) or it imagines a mixture of what the words allow."""
        identity, movement, role = code_fields(manual.routed[0])
        decided = torch.stack([identity > 0, movement >= 0, role >= 0], -1).tolist()  # [3, 3]
        out = []
        for said, stood in zip(decided, self._stands(manual)[0].tolist()):
            open_ = [f for f, d in zip(("identity", "movement", "role"), said) if not d]
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
        reads in its own language. Quantile 0: no reading stands by nearness (distance 0)."""
        if quantile == 0:
            self.stand_distance.fill_(0.0)
            return
        keys, values = self._read_texts(encoder, texts)
        closest = prototype_distances(keys, values, self.proto_keys, self.proto_values).min(-1).values
        self.stand_distance.fill_(float(closest.quantile(quantile)))


class HedgedEmmaLWM(HedgedReading, EmmaLWM):
    """EMMA-LWM whose readings of descriptions are checked against their words (module docstring).
    Its weights are an EMMA-LWM's plus the 108 prototypes (buffers `proto_keys`, `proto_values`):
    a description's key and value are what its description attention reads."""

    kind = "emma-hedged"

    def __init__(self, config: WorldModelConfig) -> None:
        super().__init__(config)
        self._init_hedging(config.decoder.hidden, config.decoder.hidden)
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

    def _read(self, manual: ManualBatch) -> tuple[torch.Tensor, torch.Tensor]:
        return self.reader.read(self.text_encoder(manual.features, manual.mask), manual.mask)

    def _hedged(self, manual: ManualBatch) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The keys and values [B, 3, W] to condition on, and where the model's reading stood."""
        if manual.features is None or manual.mask is None or manual.routed is None:
            raise ValueError("a hedged EMMA-LWM needs the manual's encoded descriptions and their words")
        keys, values = self._read(manual)
        codes, force = manual.routed, None
        if self.training and self.practice_rate > 0:
            codes, force = practice_codes(codes, self.practice_rate)
        return hedge(keys, values, codes, self.proto_keys, self.proto_values, self.stand_distance, force)

    def _tables(self, r: Readings) -> torch.Tensor:
        """[R, 17, W]: what each id reads under each reading."""
        return self.reader.attend(r.keys, r.values, self.obs_embedding(torch.arange(NUM_IDS, device=r.keys.device)))

    def condition(self, manual: ManualBatch) -> Conditioning:
        """One row per manual: in training (and with `mixture` off) the mean-prototype hedge, else
        the likeliest reading."""
        if self.training or not self.mixture:
            keys, values, _ = self._hedged(manual)
            ids = torch.arange(NUM_IDS, device=keys.device)
            return Conditioning(id_table=self.reader.attend(keys, values, self.obs_embedding(ids)))
        return super().condition(manual)

    def _stands(self, manual: ManualBatch) -> torch.Tensor:
        return super()._stands(manual) if self.mixture else self._hedged(manual)[2]

    def _read_texts(self, encoder: FrozenTextEncoder, texts: list[str]) -> tuple[torch.Tensor, torch.Tensor]:
        """The key and value [N, W] this model reads from each text alone (reader_tuning.reading)."""
        from .reader_tuning import reading  # the tuning module: only needed when fitting

        features, mask = encoder.keeping(self.config.text.max_tokens).encode(texts)
        return reading(self, features.float(), mask)


__all__ = [
    "HedgedEmmaLWM",
    "HedgedReading",
    "Readings",
    "GUESSED",
    "candidates",
    "code_fields",
    "ground_words",
    "hedge",
    "mixture_log_probs",
    "practice_codes",
    "prototype_distances",
    "readings",
    "words_code",
]

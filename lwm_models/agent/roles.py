"""Which entity is the enemy, the message and the goal, as the world model understands the manual.

The agent may not act in an unseen game, but it may ask its world model what would happen. It
imagines, from the game's real first boards, an avatar that seeks out one entity and then
another (every ordering of two of the three), and reads what the world model imagines at each
contact: the reward of the step on which the avatar reached an entity says what touching it does:
    without the message: +0.5 (picked up) means the message; death means the enemy or the goal
    carrying the message: +1 (won) means the goal; death means the enemy
Those contacts give a posterior over the six ways of giving the three entities the three roles
(`RoleBelief`). A world model that reads the manual well imagines clear contacts; one that reads
no text (Observational) cannot tell the entities apart, and its belief stays spread out. The boards
are the game's own (its 24 starts and what follows), which is what the world model was trained
on: made-up boards (an avatar placed next to an entity) were tried and the shipped EMMA-LWM
imagined no contact on most of them.

The same imagined probes show how the world model moves each entity (toward the avatar, away, or
not at all: `understood.read_back`), so a person hears what it read of the movements too before any
plan, in `RoleBelief.describe`.

A reviewer's labels are evidence too: a label that the expert would give under one assignment and
not under another moves the belief (`RoleBelief.update`), so a few labels settle what the
imagination left open. The expert is the paper's simulated human (go to the message, then to the
goal), reading the believed roles instead of the true manual.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..messenger.constants import (
    ACTION_DELTAS,
    AVATAR_CHANNEL,
    AVATAR_WITH_MESSAGE,
    ID_TO_IDENTITY,
    REWARD_DEATH,
    REWARD_PICKUP,
    REWARD_WIN,
)
from .expert import expert_actions, expert_choices
from .understood import SAID_OF, read_back

ROLES = ("enemy", "message", "goal")  # the order of role_ids and of an assignment
CONTACT_NOISE = 0.15  # how often an imagined contact is taken to show the wrong outcome
LABEL_NOISE = 0.2  # how often a reviewer's label is taken to differ from the expert's under the true roles
# The world model's contacts repeat its own reading of the manual: many of them make it sure of
# what it read, not sure that it read right. Its belief is trusted this much, the rest spread over
# every assignment, so that a person's few answers can still overturn a confident misreading.
TRUST = 0.9


@dataclass(frozen=True)
class Contact:
    """The avatar reached entity `entity` (carrying the message or not) and the world model
    imagined `outcome` for that step: "death", "pickup", "win" or "none"."""

    entity: int
    carrying: bool
    outcome: str


def outcome(reward: float) -> str:
    if reward <= REWARD_DEATH:
        return "death"
    if reward >= REWARD_WIN:
        return "win"
    if reward >= REWARD_PICKUP:
        return "pickup"
    return "none"


def seek(order: tuple[int, ...], rng: np.random.Generator):
    """An imagination policy that walks toward entity order[0] while it is on the board and the
    avatar has not changed (picked something up), then toward order[1]; a random step one time in
    five, so that the same ordering reaches its entities along several paths."""

    def act(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
        last = obs[:, -1].astype(np.int64)
        first = obs[:, 0].astype(np.int64)
        actions = rng.integers(5, size=len(last))
        for k in range(len(last)):
            avatar = last[k, AVATAR_CHANNEL]
            changed = avatar[0] != first[k, AVATAR_CHANNEL, 0]
            targets = [e for e in order if (last[k, :3, 0] == e).any()]
            if changed and len(targets) > 1 and targets[0] == order[0]:
                targets = targets[1:]
            if not targets or rng.random() < 0.2:
                continue
            cell = last[k, :3][last[k, :3, 0] == targets[0]][0, 1:]
            actions[k] = _toward(avatar[1:], cell, rng)
        return actions

    return act


def _toward(avatar: np.ndarray, cell: np.ndarray, rng: np.random.Generator) -> int:
    gaps = cell - avatar
    moves = [a for a, (dr, dc) in enumerate(ACTION_DELTAS[:4]) if dr * gaps[0] > 0 or dc * gaps[1] > 0]
    return int(rng.choice(moves)) if moves else 4


def contacts(observations: np.ndarray, rewards: np.ndarray, lengths: np.ndarray) -> list[Contact]:
    """Every step of imagined trajectories on which the avatar was on or next to exactly one entity
    (before or after the step), with what the world model imagined then. A step with two entities
    that near says nothing of either."""
    obs = np.asarray(observations, dtype=np.int64)
    out = []
    for n in range(len(obs)):
        for t in range(1, int(lengths[n])):
            before, now = obs[n, t - 1], obs[n, t]
            if before[AVATAR_CHANNEL, 0] == 0:
                continue
            near = []
            for c in range(3):
                ident = before[c, 0]
                if ident == 0:
                    continue
                cells = [o[c, 1:] for o in (before, now) if o[c, 0] == ident]
                avatars = [o[AVATAR_CHANNEL, 1:] for o in (before, now) if o[AVATAR_CHANNEL, 0] != 0]
                if min(int(np.abs(e - a).max()) for e in cells for a in avatars) <= 1:
                    near.append(int(ident))
            got = outcome(float(rewards[n, t]))
            # Only a step that ended something, or an entity alone at a touching distance, counts:
            # walking past an entity the avatar did not touch is no contact.
            touched = got != "none" or _touching(before, now)
            if len(near) == 1 and touched:
                out.append(Contact(near[0], bool(before[AVATAR_CHANNEL, 0] == AVATAR_WITH_MESSAGE), got))
    return out


def _touching(before: np.ndarray, now: np.ndarray) -> bool:
    """The avatar and an entity share a cell after the step."""
    if now[AVATAR_CHANNEL, 0] == 0:
        return False
    return any(now[c, 0] != 0 and (now[c, 1:] == now[AVATAR_CHANNEL, 1:]).all() for c in range(3))


def imagine_probes(imaginer, starts: np.ndarray, samples: int = 8, max_steps: int = 20, seed: int = 0):
    """`samples` imagined trajectories per ordering of two entities, each seeking the one and
    then the other, from the game's first boards `starts` [k, 4, 3], through `imaginer`
    (ServiceImaginer or LocalImaginer)."""
    starts = np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3)
    ids = [int(i) for i in starts[0, :3, 0] if i]
    rng = np.random.default_rng(seed)
    orders = list(itertools.permutations(ids, 2))
    chosen = starts[rng.integers(len(starts), size=len(orders) * samples)]
    policies = [seek(o, rng) for o in orders]

    def act(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
        out = np.empty(len(idx), dtype=np.int64)
        for j, policy in enumerate(policies):
            mine = np.flatnonzero(np.asarray(idx) // samples == j)
            if len(mine):
                out[mine] = policy(obs[mine], np.asarray(idx)[mine], t)
        return out

    return imaginer.rollout(chosen, act, n=len(chosen), max_steps=max_steps, seed=seed)


@dataclass
class RoleBelief:
    """A posterior over the 6 assignments of a game's 3 entity ids to (enemy, message, goal)."""

    ids: tuple[int, ...]  # the entity ids of the game
    assignments: list[tuple[int, int, int]]  # each: the ids of (enemy, message, goal)
    log_p: np.ndarray  # [6] unnormalised log posterior
    movements: dict[int, str] = field(default_factory=dict)  # id -> how the probes saw it move
    # From the manual's reading (`from_reading`): what the reading would ask a person, and the facts
    # the person stated, as the world-model server read them.
    questions: list[dict] = field(default_factory=list)
    facts: list[dict] = field(default_factory=list)
    movement_p: dict[int, float] = field(default_factory=dict)  # id -> how sure the reading is of its movement

    @classmethod
    def uniform(cls, ids) -> RoleBelief:
        ids = tuple(int(i) for i in ids if i)
        assignments = [tuple(p) for p in itertools.permutations(ids)]
        return cls(ids, assignments, np.zeros(len(assignments)))

    @classmethod
    def from_contacts(cls, ids, seen: list[Contact]) -> RoleBelief:
        """The posterior after the imagined contacts (a uniform prior). A contact of an entity
        that is not the game's is ignored; one imagined with no outcome ("none": the avatar stood
        on it and nothing happened) counts as a wrong outcome under every assignment."""
        belief = cls.uniform(ids)
        for c in seen:
            if c.entity not in belief.ids:
                continue
            for h, (_, message, goal) in enumerate(belief.assignments):
                expected = _expected(c, message, goal)
                belief.log_p[h] += np.log(1 - CONTACT_NOISE if c.outcome == expected else CONTACT_NOISE / 3)
        belief.log_p = np.log(TRUST * belief.p + (1 - TRUST) / len(belief.assignments))
        return belief

    @classmethod
    def from_reading(cls, read: dict) -> RoleBelief:
        """The belief the manual's reading states (an imagine service's `read` answer,
        world/manual_reading.py): its probabilities as they are, calibrated, with no `TRUST`
        spread, so that what a person is told and what the agent acts on are one reading."""
        ids = tuple(sorted(e["id"] for e in read["reading"]))
        assignments = [tuple(p) for p in itertools.permutations(ids)]
        given = {tuple(a): p for a, p in zip(read["assignments"], read["assignment_p"], strict=True)}
        log_p = np.log(np.maximum([given.get(a, 0.0) for a in assignments], 1e-12))
        movements = {e["id"]: SAID_OF[e["movement"]] for e in read["reading"]}
        sure = {e["id"]: float(e["movement_p"]) for e in read["reading"]}
        return cls(
            ids, assignments, log_p, movements, list(read.get("questions", [])), list(read.get("facts", [])), sure
        )

    @property
    def p(self) -> np.ndarray:
        w = np.exp(self.log_p - self.log_p.max())
        return w / w.sum()

    def best(self) -> tuple[tuple[int, int, int], float]:
        """The most likely assignment and its probability."""
        p = self.p
        h = int(p.argmax())
        return self.assignments[h], float(p[h])

    def _policies(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The weights [m] of the assignments in play and their experts' action distributions
        [m, n, 5] (even over equally good actions) in each observation [n, 4, 3]."""
        p = self.p
        live = np.flatnonzero(p >= 1e-4)
        dists = []
        for h in live:
            choices = expert_choices(np.asarray(obs), np.asarray(self.assignments[h], dtype=np.int64))
            dists.append(choices / choices.sum(1, keepdims=True))
        return p[live] / p[live].sum(), np.stack(dists)

    def votes(self, obs: np.ndarray) -> np.ndarray:
        """[n, 5]: the posterior weight of each action in each observation [n, 4, 3]."""
        w, dists = self._policies(obs)
        return np.einsum("m,mna->na", w, dists)

    def doubt(self, obs: np.ndarray) -> np.ndarray:
        """[n]: how much the assignments in play disagree on what to do in each observation: the
        weighted total variation between each one's expert and their mixture. Zero where they all
        would act alike, however indifferent the expert is between equally good moves."""
        w, dists = self._policies(obs)
        mixture = np.einsum("m,mna->na", w, dists)
        return np.einsum("m,mn->n", w, 0.5 * np.abs(dists - mixture[None]).sum(-1))

    def labels(self, obs: np.ndarray, steps: np.ndarray, seed: int = 0) -> np.ndarray:
        """[n]: the action most of the belief's weight gives each observation [n, 4, 3] at step
        `steps` (1 for the first action), each assignment's expert breaking its ties with its own
        draw, as the simulated human's does: under a sure belief these are its labels."""
        obs, steps = np.asarray(obs), np.asarray(steps)
        out = np.zeros((len(obs), 5))
        for h, w in enumerate(self.p):
            if w < 1e-4:
                continue
            ids = np.asarray(self.assignments[h], dtype=np.int64)
            for t in np.unique(steps):  # the expert draws per step index
                at = np.flatnonzero(steps == t)
                out[at, expert_actions(obs[at], ids, int(t), seed)] += w
        return out.argmax(1)

    def update(self, obs: np.ndarray, actions: np.ndarray) -> None:
        """A reviewer labelled observations [n, 4, 3] with `actions`: assignments whose expert
        could have done the same gain weight (a label is the expert's under the true roles, but
        for `LABEL_NOISE`; among equally good actions the expert picks any)."""
        obs, actions = np.asarray(obs), np.asarray(actions, dtype=np.int64)
        for h, assignment in enumerate(self.assignments):
            choices = expert_choices(obs, np.asarray(assignment, dtype=np.int64))
            k = choices.sum(1)
            hit = choices[np.arange(len(obs)), actions]
            like = np.where(hit, (1 - LABEL_NOISE) / k, LABEL_NOISE / np.maximum(5 - k, 1))
            self.log_p[h] += np.log(like).sum()

    def describe(self) -> list[dict]:
        """Per entity: the role it most probably has, how probable that is, and how the world model
        moved it in the probes (when they were imagined here)."""
        p, out = self.p, []
        for ident in self.ids:
            by_role = {r: float(sum(w for w, a in zip(p, self.assignments, strict=True) if a[k] == ident))
                       for k, r in enumerate(ROLES)}  # fmt: skip
            role = max(by_role, key=by_role.get)
            out.append({"id": ident, "identity": ID_TO_IDENTITY.get(ident, str(ident)), "role": role,
                        "p": round(by_role[role], 3)})  # fmt: skip
            if ident in self.movements:
                out[-1]["movement"] = self.movements[ident]
            if ident in self.movement_p:
                out[-1]["movement_p"] = round(self.movement_p[ident], 3)
        return out


def _expected(c: Contact, message: int, goal: int) -> str:
    if not c.carrying:
        return "pickup" if c.entity == message else "death"
    return "win" if c.entity == goal else "death"


def believe(imaginer, starts: np.ndarray, samples: int = 8, seed: int = 0) -> RoleBelief:
    """What the agent believes of the roles on these boards [k, 4, 3] before it acts: the manual's
    reading where the world model behind `imaginer` reads one (the same every time, no seed);
    else what the world model imagines in probes."""
    starts = np.asarray(starts).reshape(-1, 4, 3)
    read = getattr(imaginer, "read", None)
    if read is not None and (reading := read(starts[0])) is not None:
        return RoleBelief.from_reading(reading)
    im = imagine_probes(imaginer, starts, samples, seed=seed)
    belief = RoleBelief.from_contacts(starts[0, :3, 0], contacts(im.observations, im.rewards, im.lengths))
    belief.movements = {e["id"]: e["movement"] for e in read_back(im.observations, im.rewards, im.lengths)}
    return belief


__all__ = ["Contact", "RoleBelief", "believe", "contacts", "imagine_probes", "seek"]

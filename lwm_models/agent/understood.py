"""What the world model understood of each entity, read back from what it imagined.

A legend built by parsing the manual says what the text says, or "?" where the parser finds no
cue ("watch out for the airplane, it hunts you down"). What the reviewer needs to know is what the
world model made of it, and that shows in its imagination. The plan and its sampled futures are
already imagined, so the read-back costs nothing more:
- movement: at each imagined step, did the entity's move bring it closer to where the avatar was,
  further away, or did it stay? (The game moves entities relative to the avatar's position before
  the avatar's own move, and by half a cell a step, so most steps show no change of cell.)
- role: when a step's reward comes while the avatar is on or next to the entity, what kind it
  was: the win (the goal), the message picked up, or death (an enemy, or the goal touched before
  the message: a death alone does not say which).
Nothing seen is said as such: a role the futures never touched stays unknown.
"""

from __future__ import annotations

import numpy as np

from ..messenger.constants import ID_TO_IDENTITY, REWARD_DEATH, REWARD_PICKUP, REWARD_WIN

AVATAR = 3  # the avatar's channel in a compact observation
SAID_OF = {"chaser": "comes toward you", "fleeing": "moves away from you", "immovable": "stays put"}
"""What the read-back says of an entity imagined moving as each of the game's movements does."""


def read_back(observations: np.ndarray, rewards: np.ndarray, lengths: np.ndarray) -> list[dict]:
    """Per entity of the first observation: its imagined movement and the contacts seen.

    observations [N, T + 1, 4, 3] compact (id, row, col); rewards [N, T + 1] (index t: the reward
    of the step into observation t); lengths [N] observations per trajectory. A step's reward is
    put down to the entity nearest the avatar (on it or next to it; all of the nearest on a tie)."""
    obs = np.asarray(observations, dtype=np.int64)
    ids = [int(i) for i in obs[0, 0, :3, 0]]
    moves = {i: {"closer": 0, "farther": 0, "still": 0} for i in ids if i}
    contacts = {i: {"death": 0, "message": 0, "win": 0} for i in ids if i}
    for n in range(len(obs)):
        for t in range(1, int(lengths[n])):
            before, now = obs[n, t - 1], obs[n, t]
            avatar = before[AVATAR]
            if avatar[0] == 0:
                continue
            gaps = {}
            for c, ident in enumerate(ids):
                if ident == 0 or before[c, 0] != ident:
                    continue
                if now[c, 0] == ident:
                    d_before = np.abs(before[c, 1:] - avatar[1:]).sum()
                    d_now = np.abs(now[c, 1:] - avatar[1:]).sum()
                    m = moves[ident]
                    m["closer"] += int(d_now < d_before)
                    m["farther"] += int(d_now > d_before)
                    m["still"] += int((now[c, 1:] == before[c, 1:]).all())
                gap = _gap(before, now, c, ident)
                if gap <= 1:
                    gaps[ident] = gap
            kind = _contact(float(rewards[n, t]))
            if kind and gaps:
                nearest = min(gaps.values())
                for ident, gap in gaps.items():
                    contacts[ident][kind] += int(gap == nearest)
    out = []
    for ident in moves:
        m, seen = moves[ident], contacts[ident]
        out.append(
            {
                "id": ident,
                "identity": ID_TO_IDENTITY.get(ident, str(ident)),
                "movement": _movement(m["closer"], m["farther"], m["still"]),
                "closer": m["closer"],
                "farther": m["farther"],
                "contacts": seen,
                "role": _role(seen),
            }
        )
    return out


def _gap(before: np.ndarray, now: np.ndarray, c: int, ident: int) -> int:
    """How near the avatar came to entity c over the step, in cells (Chebyshev), before or after
    it (a collision empties the avatar's channel, or takes the message off the board)."""
    entity = [o[c, 1:] for o in (before, now) if o[c, 0] == ident]
    avatar = [o[AVATAR, 1:] for o in (before, now) if o[AVATAR, 0] != 0]
    return min((int(np.abs(e - a).max()) for e in entity for a in avatar), default=99)


def _contact(reward: float) -> str | None:
    if reward <= REWARD_DEATH:
        return "death"
    if reward >= REWARD_WIN:
        return "win"
    if reward >= REWARD_PICKUP:
        return "message"
    return None


def _movement(closer: int, farther: int, still: int) -> str:
    moves = closer + farther
    if moves == 0:
        return SAID_OF["immovable"] if still else "not seen"
    if closer >= 2 * max(farther, 1):
        return SAID_OF["chaser"]
    if farther >= 2 * max(closer, 1):
        return SAID_OF["fleeing"]
    return "moves, no clear direction"


def _role(contacts: dict) -> str:
    """A win or a pick-up says what the entity is; a death alone does not: touching the goal
    before the message kills too, so it says only what happened."""
    if contacts["win"]:
        return "the goal"
    if contacts["message"]:
        return "gives you the message"
    if contacts["death"]:
        return "you died touching it"
    return "not seen"


def describe(entry: dict) -> str:
    """One line for a legend: "comes toward you (9 of 11 moves); kills you on contact (3 times)"."""
    moves = entry["closer"] + entry["farther"]
    movement = entry["movement"]
    if moves:
        toward = entry["closer"] if movement != SAID_OF["fleeing"] else entry["farther"]
        movement += f" ({toward} of {moves} moves)"
    role = entry["role"]
    if role != "not seen":
        kind = {"the goal": "win", "gives you the message": "message"}.get(role, "death")
        count = entry["contacts"][kind]
        role += f" ({count} time{'s' if count > 1 else ''})"
    else:
        role = "its role not seen in these futures"
    return f"{movement}; {role}"


def read_roles(roles: list[dict]) -> str:
    """Roles read by the probes (agent/roles.py) as a list: "dog the enemy, comes toward you (93%
    sure), ..."; the movement where the probes saw one."""
    said = []
    for entry in roles:
        sure = "unsure" if entry["p"] < 0.6 else f"{entry['p']:.0%} sure"
        moves = f", {entry['movement']}" if entry.get("movement") not in (None, "not seen") else ""
        if "movement_p" in entry:  # the manual's reading says how sure it is of each
            moving = "unsure" if entry["movement_p"] < 0.6 else f"{entry['movement_p']:.0%} sure"
            said.append(f"{entry['identity']} the {entry['role']} ({sure}){moves} ({moving})")
            continue
        said.append(f"{entry['identity']} the {entry['role']}{moves} ({sure})")
    return ", ".join(said)


def believed(roles: list[dict]) -> str:
    """The roles the agent acts on (a plan's "roles", agent/roles.py), as one sentence: what a
    reviewer checks first, since a policy taught under a wrong role heads for the wrong entity.
    Where no role is likelier than not, the sentence says the agent is guessing: a manual that
    says nothing usable must not read like one that was understood."""
    said = "the agent acts on: " + read_roles(roles)
    if roles and all(entry["p"] < 0.5 for entry in roles):
        said += " - a guess: the manual says nothing the agent can use about who is who"
    return said


__all__ = ["SAID_OF", "believed", "describe", "read_back", "read_roles"]

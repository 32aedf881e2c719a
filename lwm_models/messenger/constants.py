"""Fixed facts of Messenger stage 2 (docs/game.md states them)."""

from __future__ import annotations

import itertools

GRID = 10
"""The observation grid is GRID x GRID cells."""
HALF_MAX = 2 * (GRID - 1)
"""Positions are kept in half-cells, 0..HALF_MAX on each axis."""
NUM_CHANNELS = 4
"""Three entity channels (permuted per episode) and the avatar channel (last)."""
AVATAR_CHANNEL = 3
DEFAULT_MAX_STEPS = 32
"""The paper's time limit: 32 actions, 33 observations."""

IDENTITIES: dict[str, int] = {
    "airplane": 2,
    "mage": 3,
    "dog": 4,
    "bird": 5,
    "fish": 6,
    "scientist": 7,
    "thief": 8,
    "ship": 9,
    "ball": 10,
    "robot": 11,
    "queen": 12,
    "sword": 13,
}
ID_TO_IDENTITY: dict[int, str] = {v: k for k, v in IDENTITIES.items()}
EMPTY = 0
WALL = 14
AVATAR_NO_MESSAGE = 15
AVATAR_WITH_MESSAGE = 16
NUM_IDS = 17
"""Ids 0..16 can appear in an observation."""

ROLES: tuple[str, ...] = ("enemy", "message", "goal")
MOVEMENTS: tuple[str, ...] = ("chaser", "fleeing", "immovable")

# Actions and their (d_row, d_col) in cells.
UP, DOWN, LEFT, RIGHT, STAY = 0, 1, 2, 3, 4
NUM_ACTIONS = 5
ACTION_NAMES: tuple[str, ...] = ("up", "down", "left", "right", "stay")
ACTION_DELTAS: tuple[tuple[int, int], ...] = ((-1, 0), (1, 0), (0, -1), (0, 1), (0, 0))

REWARD_DEATH = -1.0
REWARD_PICKUP = 0.5
REWARD_WIN = 1.0

CORNERS: tuple[tuple[int, int], ...] = ((2, 2), (2, 7), (7, 2), (7, 7))
START_ORDER: tuple[str, ...] = ("avatar", "enemy", "message", "goal")
STARTS: tuple[tuple[tuple[int, int], ...], ...] = tuple(itertools.permutations(CORNERS))
"""The 24 starts. STARTS[i][k] is the cell of START_ORDER[k]; the order is
itertools.permutations(CORNERS), i.e. lexicographic in the corner order above. Evaluation that must
cover every start uses start = episode % 24."""

# Training triples: each identity has exactly 2 roles x 2 movements in training (docs/game.md).
_TRAIN_GROUPS: tuple[tuple[tuple[str, ...], tuple[str, ...], tuple[str, ...]], ...] = (
    (("airplane", "ball", "dog", "sword"), ("message", "goal"), ("chaser", "immovable")),
    (("bird", "fish", "mage", "robot"), ("enemy", "goal"), ("chaser", "fleeing")),
    (("queen", "scientist", "ship", "thief"), ("enemy", "message"), ("fleeing", "immovable")),
)
Triple = tuple[str, str, str]
"""(identity, movement, role)."""
TRAIN_TRIPLES: frozenset[Triple] = frozenset(
    (ident, mov, role) for idents, roles, movs in _TRAIN_GROUPS for ident in idents for role in roles for mov in movs
)
ALL_TRIPLES: tuple[Triple, ...] = tuple(
    (ident, mov, role) for ident in IDENTITIES for mov in MOVEMENTS for role in ROLES
)

SPLITS: tuple[str, ...] = (
    "train",
    "newcombo-dev",
    "newcombo-test",
    "newattr-dev",
    "newattr-test",
    "newall-dev",
    "newall-test",
)

"""What the tests share: a manual and a start observation of newall-test game 0's kind, random
games, and the shipped world-model server on that manual."""

from __future__ import annotations

import numpy as np

MANUAL = [
    "the plane is the deadly enemy and it chases you.",
    "the ball has the secret message and runs away from you.",
    "the robot is the goal and never moves.",
]
OBS = [[2, 2, 7], [10, 7, 2], [11, 7, 7], [15, 2, 2]]


def random_games(n: int, seed: int) -> list:
    """n games of random triples (any identities, movements; one of each role)."""
    from lwm_models.messenger import GameSpec
    from lwm_models.messenger.constants import IDENTITIES, MOVEMENTS, ROLES

    rng = np.random.default_rng(seed)
    names = list(IDENTITIES)
    games = []
    for _ in range(n):
        ids = rng.choice(len(names), 3, replace=False)
        games.append(GameSpec.from_triples([(names[ids[k]], MOVEMENTS[rng.integers(3)], ROLES[k]) for k in range(3)]))
    return games


def shipped_server():
    """The world-model server on the shipped EMMA-LWM, one torch thread, with MANUAL as its manual."""
    import torch

    from lwm_models.world.frozen_text import FrozenTextEncoder
    from lwm_models.world.model_server import WorldModelServer

    torch.set_num_threads(1)
    s = WorldModelServer(encoder=FrozenTextEncoder())
    s.set_manual(MANUAL, "test")
    return s

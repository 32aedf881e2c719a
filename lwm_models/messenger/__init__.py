"""Messenger stage 2: the game, its batched engine and the behaviour policies (no ROS here)."""

from .constants import ACTION_NAMES, IDENTITIES, MOVEMENTS, ROLES, STARTS, TRAIN_TRIPLES, Triple
from .engine import BatchedMessenger, compact_to_grid, grid_to_compact
from .env import MessengerEnv
from .policies import POLICIES, behaviour_actions, policy_index
from .rollout import Rollouts, rollout
from .spec import EntitySpec, GameSpec

__all__ = [
    "ACTION_NAMES",
    "IDENTITIES",
    "MOVEMENTS",
    "POLICIES",
    "ROLES",
    "STARTS",
    "TRAIN_TRIPLES",
    "BatchedMessenger",
    "EntitySpec",
    "GameSpec",
    "MessengerEnv",
    "Rollouts",
    "Triple",
    "behaviour_actions",
    "compact_to_grid",
    "grid_to_compact",
    "policy_index",
    "rollout",
]

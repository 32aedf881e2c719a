"""A real game as the environment node serves it: chosen by split and index, reset and stepped,
its state and manual as message payloads (msgs_json/state and manual)."""

from __future__ import annotations

from ..errors import LwmError
from ..messenger.constants import NUM_ACTIONS
from ..messenger.engine import grid_to_compact
from ..messenger.env import MessengerEnv
from ..text import DescriptionPools
from .episode import Episode
from .splits import load_split


class GameSession:
    def __init__(
        self, split: str = "newall-test", index: int = 0, pools: DescriptionPools | None = None, max_steps: int = 32
    ) -> None:
        self.pools = pools or DescriptionPools.generated()
        self.max_steps = max_steps
        self.env: MessengerEnv | None = None
        self.select(split, index)

    def select(self, split: str, index: int) -> None:
        try:
            games = load_split(split)
        except KeyError as exc:
            raise LwmError(str(exc).strip("'\"")) from None
        if not 0 <= index < len(games):
            raise LwmError(f"game index must be in 0..{len(games) - 1} for {split}, got {index}")
        self.split, self.index = split, index
        self.env = MessengerEnv(games[index], pools=self.pools, split=split, max_steps=self.max_steps)
        self.obs = None

    def reset(self, seed: int = 0, split: str | None = None, index: int | None = None, restart: bool = False) -> dict:
        """A new episode; `restart`: the current one again (same seed and board) as its next attempt,
        which the planner reviews afresh."""
        if restart:
            if self.obs is None:
                raise LwmError("no episode to restart yet: reset first")
            episode = self.episode.restarted()
        else:
            if split is not None or index is not None:
                self.select(split or self.split, self.index if index is None else index)
            episode = Episode(self.split, self.index, seed)
        return self.resume(episode)

    def resume(self, episode: Episode) -> dict:
        """Play `episode` from its start again, the same attempt (an environment restarted, or a
        run continued, returns to the episode under review rather than to its first seed)."""
        if (episode.split, episode.index) != (self.split, self.index):
            self.select(episode.split, episode.index)
        self.episode, self.seed = episode, episode.seed
        self.episode_id = episode.id
        self.obs, self.info = self.env.reset(seed=episode.seed)
        self.reward, self.total, self.outcome = 0.0, 0.0, "running"
        return self.state()

    def step(self, action: int) -> dict:
        if self.obs is None:
            raise LwmError("no episode: reset first")
        if self.env.done:
            raise LwmError(f"the episode has ended ({self.outcome}); reset first")
        if not isinstance(action, int) or not 0 <= action < NUM_ACTIONS:
            raise LwmError(f"action must be an integer in 0..{NUM_ACTIONS - 1}, got {action!r}")
        self.obs, reward, terminated, truncated, self.info = self.env.step(action)
        self.reward = float(reward)
        self.total += self.reward
        if terminated:
            self.outcome = "won" if self.env.won else "died"
        elif truncated:
            self.outcome = "time_limit"
        return self.state()

    def state(self) -> dict:
        return {
            "episode_id": self.episode_id,
            "seed": self.seed,
            "attempt": self.episode.attempt,
            "game": {"split": self.split, "index": self.index},
            "t": self.env.t,
            "observation": grid_to_compact(self.obs).tolist(),
            "reward": self.reward,
            "done": self.env.done,
            "return": self.total,
            "outcome": self.outcome,
        }

    def manual(self) -> dict:
        return {"descriptions": list(self.info["manual"]), "source": "env", "episode_id": self.episode_id}

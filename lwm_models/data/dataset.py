"""The Messenger-WM trajectory dataset: generation and a memory-mapped reader.

On-disk format (version 1), one directory:

    index.json                 format, version, seeds, text source, per-split counts, this layout
    games.json                 the game splits (GameSplits.to_json)
    <split>/observations.npy   uint8 [S, 4, 3]   per observation, per channel (id, row, col);
                                                 channels 0-2 entities (episode's order), 3 avatar;
                                                 an empty channel is (0, 0, 0)
    <split>/actions.npy        uint8 [S]         action that led to the observation (0 = dummy
                                                 for an episode's first observation)
    <split>/rewards.npy        float32 [S]       reward of the step that led to it (0 at first)
    <split>/dones.npy          bool [S]          the episode ended with this observation
    <split>/episode_offsets.npy int64 [E + 1]    episode e is rows offsets[e]:offsets[e + 1]
    <split>/episode_games.npy  int32 [E]         index of the game in games.json[split]
    <split>/episode_policies.npy int8 [E]        index into POLICIES
    <split>/episode_seeds.npy  int64 [E]         the engine seed (replays the episode exactly)
    <split>/episode_starts.npy int8 [E]          index into STARTS
    <split>/manuals.npy        int32 [E, 3]      the manual, as indices into texts.json
    <split>/parses.npy         int16 [E, 3]      the true (identity, movement, role) of each
                                                 manual description: indices into ALL_TRIPLES
    <split>/texts.json         list[str]         the split's distinct descriptions

Everything is plain .npy (no pickles), so `np.load(..., mmap_mode="r")` maps it without reading.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DatasetError
from ..messenger.constants import ALL_TRIPLES, DEFAULT_MAX_STEPS, SPLITS
from ..messenger.engine import compact_to_grid
from ..messenger.policies import POLICIES
from ..messenger.rollout import rollout
from ..messenger.spec import GameSpec
from .splits import GameSplits, default_splits

FORMAT = "messenger-wm-trajectories"
VERSION = 1
TRAIN_EPISODES_PER_GAME = 66
_TRIPLE_INDEX = {t: i for i, t in enumerate(ALL_TRIPLES)}
_ARRAYS = (
    "observations",
    "actions",
    "rewards",
    "dones",
    "episode_offsets",
    "episode_games",
    "episode_policies",
    "episode_seeds",
    "episode_starts",
    "manuals",
    "parses",
)


def episode_seeds(seed: int, split: str, count: int) -> np.ndarray:
    """Engine seeds of a split's episodes: distinct across splits and runs of different seeds."""
    base = (int(seed) << 32) | (SPLITS.index(split) << 28)
    return base + np.arange(count, dtype=np.int64)


def plan_episodes(split: str, num_games: int, seed: int, train_episodes_per_game: int) -> tuple[np.ndarray, np.ndarray]:
    """(game index, policy) of every episode: train has `train_episodes_per_game` episodes per game
    with a uniformly drawn policy; dev and test one episode per game per policy."""
    if split == "train":
        games = np.repeat(np.arange(num_games), train_episodes_per_game)
        policies = np.random.default_rng([seed, 0x504F4C]).integers(len(POLICIES), size=games.size)
    else:
        games = np.repeat(np.arange(num_games), len(POLICIES))
        policies = np.tile(np.arange(len(POLICIES)), num_games)
    return games.astype(np.int32), policies.astype(np.int8)


def generate_split(
    out: Path,
    split: str,
    games: list[GameSpec],
    pools,
    seed: int,
    train_episodes_per_game: int = TRAIN_EPISODES_PER_GAME,
    max_steps: int = DEFAULT_MAX_STEPS,
    chunk: int = 16384,
    progress: Callable[[int], None] | None = None,
) -> dict:
    """Generate and write one split's episodes; returns its counts for index.json."""
    game_idx, policies = plan_episodes(split, len(games), seed, train_episodes_per_game)
    seeds = episode_seeds(seed, split, game_idx.size)
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("observations", "actions", "rewards", "dones")}
    lengths, starts = [], []
    for lo in range(0, game_idx.size, chunk):
        hi = min(lo + chunk, game_idx.size)
        ro = rollout([games[g] for g in game_idx[lo:hi]], seeds[lo:hi], policies[lo:hi], max_steps=max_steps)
        valid = np.arange(ro.actions.shape[1])[None, :] < ro.lengths[:, None]
        parts["observations"].append(ro.observations[valid])
        parts["actions"].append(ro.actions[valid])
        parts["rewards"].append(ro.rewards[valid])
        parts["dones"].append(ro.dones[valid])
        lengths.append(ro.lengths)
        starts.append(ro.starts)
        if progress:
            progress(hi - lo)

    manuals, parses, texts = _draw_manuals(split, [games[g] for g in game_idx], pools, seed)
    lengths_all = np.concatenate(lengths)
    arrays = {
        **{k: np.concatenate(v) for k, v in parts.items()},
        "episode_offsets": np.concatenate([[0], np.cumsum(lengths_all)]).astype(np.int64),
        "episode_games": game_idx,
        "episode_policies": policies,
        "episode_seeds": seeds,
        "episode_starts": np.concatenate(starts).astype(np.int8),
        "manuals": manuals,
        "parses": parses,
    }
    split_dir = out / split
    split_dir.mkdir(parents=True, exist_ok=True)
    for name, arr in arrays.items():
        np.save(split_dir / f"{name}.npy", arr)
    (split_dir / "texts.json").write_text(json.dumps(texts, ensure_ascii=False))
    return {
        "episodes": int(game_idx.size),
        "observations": int(arrays["observations"].shape[0]),
        "games": len(games),
        "distinct_texts": len(texts),
        "mean_return_by_policy": {
            POLICIES[p]: float(_returns(arrays)[policies == p].mean())
            for p in range(len(POLICIES))
            if (policies == p).any()
        },
    }


def _returns(arrays: dict[str, np.ndarray]) -> np.ndarray:
    return np.add.reduceat(arrays["rewards"], arrays["episode_offsets"][:-1])


def _draw_manuals(split: str, games: list[GameSpec], pools, seed: int) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """One manual per episode: a description per entity from the split's pool, in random order."""
    rng = np.random.default_rng([seed, SPLITS.index(split), 0x4D414E])
    text_ids: dict[str, int] = {}
    manuals = np.zeros((len(games), 3), dtype=np.int32)
    parses = np.zeros((len(games), 3), dtype=np.int16)
    orders = np.argsort(rng.random((len(games), 3)), axis=1)  # a uniform permutation per episode
    for e, game in enumerate(games):
        triples = [game.triples[i] for i in orders[e]]
        for k, text in enumerate(pools.draw(split, triples, rng)):
            manuals[e, k] = text_ids.setdefault(text, len(text_ids))
            parses[e, k] = _TRIPLE_INDEX[triples[k]]
    return manuals, parses, list(text_ids)


def generate_dataset(
    out: str | Path,
    pools,
    seed: int = 0,
    split_seed: int = 0,
    train_episodes_per_game: int = TRAIN_EPISODES_PER_GAME,
    max_games: int | None = None,
    splits: tuple[str, ...] = SPLITS,
    max_steps: int = DEFAULT_MAX_STEPS,
    text_source: str = "generated",
    progress_factory: Callable[[int], Callable[[int], None]] | None = None,
) -> dict:
    """Generate the benchmark into `out` and return the index written to index.json.

    `max_games` keeps only the first games of each split (for tests and quick looks);
    `progress_factory(total_episodes)` returns a callback that is told how many episodes are done.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    game_splits = default_splits(split_seed)
    chosen = {s: game_splits[s][:max_games] if max_games else game_splits[s] for s in splits}
    total = sum(len(g) * (train_episodes_per_game if s == "train" else len(POLICIES)) for s, g in chosen.items())
    progress = progress_factory(total) if progress_factory else None
    began = time.perf_counter()
    counts = {
        s: generate_split(out, s, games, pools, seed, train_episodes_per_game, max_steps, progress=progress)
        for s, games in chosen.items()
    }
    GameSplits(split_seed, chosen).save(out / "games.json")
    index = {
        "format": FORMAT,
        "version": VERSION,
        "seed": seed,
        "split_seed": split_seed,
        "text_source": text_source,
        "max_steps": max_steps,
        "train_episodes_per_game": train_episodes_per_game,
        "max_games": max_games,
        "policies": list(POLICIES),
        "splits": counts,
        "seconds": round(time.perf_counter() - began, 2),
        "layout": __doc__,
    }
    (out / "index.json").write_text(json.dumps(index, indent=2))
    return index


@dataclass
class Episode:
    """One episode read from the dataset."""

    observations: np.ndarray  # [L, 4, 3] compact
    actions: np.ndarray  # [L]
    rewards: np.ndarray  # [L]
    dones: np.ndarray  # [L]
    manual: list[str]
    parse: list[tuple[str, str, str]]
    game: GameSpec
    policy: str
    seed: int
    start: int

    @property
    def grids(self) -> np.ndarray:
        return compact_to_grid(self.observations)


class TrajectoryDataset:
    """A split of a generated dataset, memory-mapped: opening it reads only the index files."""

    def __init__(self, root: str | Path, split: str) -> None:
        self.root = Path(root)
        index_path = self.root / "index.json"
        if not index_path.is_file():
            raise DatasetError(f"{self.root} is not a Messenger-WM dataset (no index.json); run 'lwm data generate'")
        try:
            self.index = json.loads(index_path.read_text())
        except json.JSONDecodeError as exc:
            raise DatasetError(f"{index_path} is not valid JSON: {exc}") from None
        if self.index.get("format") != FORMAT or self.index.get("version") != VERSION:
            raise DatasetError(
                f"{index_path}: expected {FORMAT} version {VERSION}, got "
                f"{self.index.get('format')} version {self.index.get('version')}"
            )
        if split not in self.index["splits"]:
            raise DatasetError(f"split {split!r} is not in {self.root}; it has {list(self.index['splits'])}")
        self.split = split
        d = self.root / split
        try:
            for name in _ARRAYS:
                setattr(self, name, np.load(d / f"{name}.npy", mmap_mode="r"))
            self.texts: list[str] = json.loads((d / "texts.json").read_text())
        except (OSError, ValueError) as exc:
            raise DatasetError(f"{d}: cannot read the split's files: {exc}") from None
        games = json.loads((self.root / "games.json").read_text())["splits"][split]
        self.games = [GameSpec.from_triples(g) for g in games]
        expected = self.index["splits"][split]
        if len(self.episode_games) != expected["episodes"] or len(self.observations) != expected["observations"]:
            raise DatasetError(f"{d}: arrays do not match index.json (truncated or mixed files?)")

    def __len__(self) -> int:
        return len(self.episode_games)

    @property
    def human_written(self) -> bool:
        """Whether its manuals were drawn from human-written files (`lwm data generate --text-source`),
        not from the project's generator."""
        return self.index.get("text_source", "generated") != "generated"

    def lengths(self) -> np.ndarray:
        return np.diff(self.episode_offsets)

    def __getitem__(self, e: int) -> Episode:
        if not -len(self) <= e < len(self):
            raise IndexError(f"episode {e} out of range for {len(self)} episodes")
        e = e % len(self)
        lo, hi = int(self.episode_offsets[e]), int(self.episode_offsets[e + 1])
        return Episode(
            observations=np.asarray(self.observations[lo:hi]),
            actions=np.asarray(self.actions[lo:hi]),
            rewards=np.asarray(self.rewards[lo:hi]),
            dones=np.asarray(self.dones[lo:hi]),
            manual=[self.texts[i] for i in self.manuals[e]],
            parse=[ALL_TRIPLES[i] for i in self.parses[e]],
            game=self.games[int(self.episode_games[e])],
            policy=POLICIES[int(self.episode_policies[e])],
            seed=int(self.episode_seeds[e]),
            start=int(self.episode_starts[e]),
        )

    def returns(self) -> np.ndarray:
        return np.add.reduceat(np.asarray(self.rewards), np.asarray(self.episode_offsets[:-1]))


def dataset_source_problem(data_dir: str | Path, split: str, sources: Sequence[str]) -> str | None:
    """Why `sources` cannot be measured on `data_dir`, or None. "dataset" stands for the human-written
    descriptions, and a directory generated without them (no `--text-source`) holds the generator's:
    measured there, that source would be the generator's text under the dataset's name."""
    if "dataset" not in sources or TrajectoryDataset(data_dir, split).human_written:
        return None
    return (
        f"{data_dir} holds the generator's descriptions, not the dataset's human-written ones: generate it "
        "with 'lwm data generate --text-source text_train.json text_val.json', or leave out the source 'dataset'"
    )

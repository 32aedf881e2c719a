"""How the agent's policy learns: behaviour cloning of the expert on the training games (the
warm start), online imitation inside a world model (docs/benchmarks.md, "Table 3"), and evaluation in the real game.

Online imitation: the learner acts in imagination (sampling), the expert (go_to_goal reading the
true manual, i.e. the simulated human) labels every imagined state, and the loss is
-log pi(expert action). Only imagined states are used: the agent never acts in the unseen game
before evaluation.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
import torch
import torch.nn.functional as F

from ..data.dataset import TrajectoryDataset
from ..messenger.constants import STARTS
from ..messenger.engine import BatchedMessenger
from ..messenger.spec import GameSpec
from ..stats import mean_interval
from ..world.base import ManualBatch, WorldModel
from ..world.imagine import Imagination, Policy
from .expert import expert_actions, role_ids
from .policy import HISTORY, EmmaPolicy, act, stack_history


def _history_at(obs: np.ndarray, offsets: np.ndarray, t: np.ndarray) -> np.ndarray:
    """[B, 3, 4, 3]: observations t-2..t of each sampled episode (clamped at its start)."""
    idx = offsets[:, None] + np.maximum(t[:, None] + np.arange(-HISTORY + 1, 1)[None, :], 0)
    return obs[idx]


def pretrain(
    policy: EmmaPolicy,
    data: TrajectoryDataset,
    features: torch.Tensor,
    lengths: torch.Tensor,
    steps: int = 2000,
    batch: int = 128,
    lr: float = 1e-3,
    seed: int = 0,
    progress=None,
) -> list[float]:
    """Behaviour cloning on states of the training episodes, labelled by the expert.

    features/lengths: the frozen encodings of data.texts ([num_texts, T, F], [num_texts]).
    """
    rng = np.random.default_rng(seed)
    opt = torch.optim.Adam(policy.parameters(), lr=lr)
    obs = np.asarray(data.observations)
    offsets = np.asarray(data.episode_offsets)
    ep_len = np.diff(offsets)
    ids_by_game = np.stack([role_ids(g) for g in data.games])
    losses = []
    policy.train()
    for step in range(steps):
        e = rng.integers(len(ep_len), size=batch)
        t = (rng.random(batch) * (ep_len[e] - 1)).astype(np.int64)  # states that have a next action
        hist = _history_at(obs, offsets[e], t)
        labels = np.empty(batch, dtype=np.int64)
        games = np.asarray(data.episode_games)[e]
        seeds = np.asarray(data.episode_seeds)[e]
        for k in range(batch):  # the expert is vectorised over games with the same step index
            labels[k] = expert_actions(hist[k : k + 1, -1], ids_by_game[games[k]], int(t[k]) + 1, seeds[k])[0]
        manual = manual_from_text_ids(np.asarray(data.manuals)[e], features, lengths)
        logits = policy(torch.from_numpy(hist), policy.id_values(manual))
        loss = F.cross_entropy(logits, torch.from_numpy(labels))
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
        if progress:
            progress(step, loss.item())
    policy.eval()
    return losses


def fit_labels(
    policy: EmmaPolicy,
    manual: ManualBatch,
    history: np.ndarray,
    labels: np.ndarray,
    steps: int,
    lr: float,
    batch: int = 256,
    seed: int = 0,
    optimizer: torch.optim.Optimizer | None = None,
    should_stop: Callable[[], bool] = lambda: False,
) -> list[float]:
    """Supervised steps on (3-observation history, expert action) pairs of one manual: minibatches
    of `batch` drawn at random (the whole set when it is smaller). Returns the losses. Pass an
    optimizer to carry its state across calls (online imitation); else a fresh Adam at `lr`.
    `should_stop` is asked before every step: a person's "stop" ends a round's fitting at once
    (a round is hundreds of steps, seconds on a loaded machine)."""
    h = torch.from_numpy(np.ascontiguousarray(history))
    y = torch.as_tensor(np.asarray(labels, dtype=np.int64))
    opt = optimizer or torch.optim.Adam(policy.parameters(), lr=lr)
    rng = np.random.default_rng(seed)
    losses = []
    policy.train()
    for _ in range(steps):
        if should_stop():
            break
        i = torch.from_numpy(rng.integers(len(h), size=batch)) if len(h) > batch else slice(None)
        loss = F.cross_entropy(policy(h[i], policy.id_values(manual).expand(len(y[i]), -1, -1)), y[i])
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    policy.eval()
    return losses


def manual_from_text_ids(text_ids: np.ndarray, features: torch.Tensor, lengths: torch.Tensor) -> ManualBatch:
    idx = torch.from_numpy(np.asarray(text_ids, dtype=np.int64))
    f = features[idx].float()
    mask = torch.arange(f.shape[2])[None, None, :] < lengths[idx][..., None]
    return ManualBatch(f, mask)


@dataclass
class RealEvaluation:
    returns: np.ndarray  # [episodes]
    wins: int
    deaths: int

    @property
    def mean(self) -> float:
        return float(self.returns.mean())

    def interval(self) -> tuple[float, float]:
        """95% t interval of the mean return over the episodes."""
        _, lo, hi = mean_interval(self.returns)
        return lo, hi


def evaluate_real(
    policy: EmmaPolicy, game: GameSpec, manual: ManualBatch, episodes: int = 48, seed: int = 0, max_steps: int = 32
) -> RealEvaluation:
    """Argmax actions in the real game: episode i starts at STARTS[i % 24] (48 = each start twice)."""
    engine = BatchedMessenger(max_steps=max_steps)
    engine.reset([game] * episodes, seed * 100_000 + np.arange(episodes), np.arange(episodes) % len(STARTS))
    id_values = policy.id_values(manual).detach().expand(episodes, -1, -1)
    history = [engine.compact_observation()]
    total = np.zeros(episodes, dtype=np.float64)
    while not engine.done.all():
        obs = np.stack(history[-HISTORY:], axis=1)
        actions = act(policy, stack_history(obs), id_values, sample=False)
        rewards, _, _, _ = engine.step(actions.astype(np.int64))
        total += rewards
        history.append(engine.compact_observation())
    return RealEvaluation(total, int(engine.won.sum()), int((~engine.alive).sum()))


def expert_labeller(game: GameSpec, seed: int = 0) -> Callable[[np.ndarray, int], np.ndarray]:
    """The simulated human: go_to_goal reading the game's true manual labels observations."""
    ids = role_ids(game)
    return lambda obs, t: expert_actions(obs, ids, t, seed)


@dataclass
class Budget:
    """What learning in one game may spend. The paper: 2,000 updates of 10 imagined episodes; here
    fewer rounds, each followed by several minibatch steps on every state labelled so far."""

    iterations: int = field(
        default=40, metadata={"help": "online imitation: rounds of imagination with the current policy"}
    )
    episodes: int = field(default=16, metadata={"help": "imagined episodes per round"})
    grad_steps: int = field(
        default=10,
        metadata={"help": "minibatch steps after each round (filtered BC: iterations x grad_steps)"},
    )
    batch: int = field(default=256, metadata={"help": "labelled states per minibatch step"})
    lr: float = field(default=1e-3, metadata={"help": "Adam learning rate of the policy"})
    plans_per_start: int = field(default=8, metadata={"help": "filtered BC: expert plans imagined from each start"})
    keep: float = field(
        default=0.25,
        metadata={"help": "filtered BC: the share of each start's plans (highest imagined return) cloned"},
    )
    eval_episodes: int = field(default=48, metadata={"help": "real episodes that evaluate the learnt policy"})
    overlap: bool = field(
        default=False,
        metadata={
            "help": "online imitation: imagine round u+1 while learning from round u (acting lags a round; "
            "the review loop's default)"
        },
    )
    constrained: bool = field(
        default=False,
        metadata={"help": "imagine under the game's rules (decoding constraints), not the world model's raw samples"},
    )


def start_observations(game: GameSpec, seed: int = 0) -> np.ndarray:
    """[24, 4, 3]: the game's first observation from each of its 24 starts. Resetting the game is
    not acting in it, so the agent may imagine from these."""
    engine = BatchedMessenger()
    engine.reset([game] * len(STARTS), seed * 1_000 + np.arange(len(STARTS)), np.arange(len(STARTS)))
    return engine.compact_observation()


def imagine_round(
    policy: EmmaPolicy,
    imaginer,
    manual: ManualBatch,
    starts: np.ndarray,
    episodes: int,
    rng: np.random.Generator,
    gen: torch.Generator,
    seed: int,
    max_steps: int = 32,
    constrained: bool = False,
) -> Imagination:
    """One round of learning in imagination: `episodes` trajectories of `policy` (sampling with
    `gen`) through `imaginer`, from starts [k, 4, 3] drawn with `rng`."""
    chosen = starts[rng.integers(len(starts), size=episodes)]
    learner = sampling_policy(policy, manual, episodes, gen)
    return imaginer.rollout(chosen, learner, n=episodes, max_steps=max_steps, seed=seed, constrained=constrained)


def sampling_policy(policy: EmmaPolicy, manual: ManualBatch, n: int, gen: torch.Generator) -> Policy:
    """An imagination policy callback for up to n trajectories: `policy` sampling its actions with `gen`."""
    with torch.no_grad():
        id_values = policy.id_values(manual).expand(n, -1, -1)

    def sample(obs: np.ndarray, idx: np.ndarray, t: int) -> np.ndarray:
        return act(policy, stack_history(obs), id_values[: len(idx)], sample=True, generator=gen)

    return sample


def imagined_states(im: Imagination, max_steps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Every state with a next action in imagined trajectories, step by step: histories
    [m, 3, 4, 3], observations [m, 4, 3], their step index (0 = the start) and trajectory."""
    return _states_with_actions(im.observations, im.lengths, max_steps)


def _states_with_actions(
    observations: np.ndarray, lengths: np.ndarray, max_steps: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    hist, obs, steps, traj = [], [], [], []
    for t in range(1, max_steps + 1):
        alive = np.flatnonzero(lengths > t)  # trajectories still running at step t-1
        if len(alive) == 0:
            break
        hist.append(stack_history(observations[alive, :t]))
        obs.append(observations[alive, t - 1])
        steps.append(np.full(len(alive), t - 1))
        traj.append(alive)
    return np.concatenate(hist), np.concatenate(obs), np.concatenate(steps), np.concatenate(traj)


def labelled_states(
    observations: np.ndarray,
    lengths: np.ndarray,
    max_steps: int,
    labeller: Callable[[np.ndarray, int], np.ndarray] | None = None,
    actions: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Histories [m, 3, 4, 3] of every state with a next action in imagined trajectories, and their
    labels: labeller(observations [n, 4, 3], t), called once per step, or the trajectories' own
    `actions` (actions[:, t] is taken in the state at t-1)."""
    hist, obs, steps, traj = _states_with_actions(observations, lengths, max_steps)
    if labeller is None:
        return hist, actions[traj, steps + 1].astype(np.int64)
    labels = np.empty(len(obs), dtype=np.int64)
    for t in np.unique(steps):  # states come step by step: one labeller call per step
        at = np.flatnonzero(steps == t)
        labels[at] = labeller(obs[at], int(t) + 1)
    return hist, labels


RoundLabeller = Callable[[Imagination, int], tuple[np.ndarray, np.ndarray]]
"""label_round(imagined round, round number) -> (histories [m, 3, 4, 3], labels [m]) of the states
the reviewer labelled (all of them for the simulated human; the ones a person chose)."""


def expert_rounds(labeller: Callable[[np.ndarray, int], np.ndarray], max_steps: int = 32) -> RoundLabeller:
    """The simulated human labelling every state of a round, in process."""
    return lambda im, _round: labelled_states(im.observations, im.lengths, max_steps, labeller)


@dataclass
class LabelledSet:
    """The (history, expert action) pairs a policy has been taught in one game (DAgger aggregates)."""

    history: list[np.ndarray] = field(default_factory=list)
    labels: list[np.ndarray] = field(default_factory=list)

    def add(self, history: np.ndarray, labels: np.ndarray) -> None:
        if len(labels):
            self.history.append(np.asarray(history, dtype=np.uint8))
            self.labels.append(np.asarray(labels, dtype=np.int64))

    def __len__(self) -> int:
        return int(sum(len(y) for y in self.labels))

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.concatenate(self.history), np.concatenate(self.labels)

    def without(self, history: np.ndarray) -> LabelledSet:
        """This set less every pair whose state is one of `history` (a correction replaces them)."""
        if not len(self):
            return LabelledSet()
        h, y = self.arrays()
        drop = {np.asarray(x, dtype=np.uint8).tobytes() for x in history}
        keep = np.array([x.tobytes() not in drop for x in h], dtype=bool)
        out = LabelledSet()
        out.add(h[keep], y[keep])
        return out


class LearningBehind:
    """Learning a round behind acting. Overlapped, a copy of the policy (`acting`) imagines round
    u+1 while the policy itself learns from round u in a second thread (torch releases the GIL in
    its kernels, and the world model may be another process), as in asynchronous DAgger; the copy
    takes the policy's weights each time a round's learning has ended. Not overlapped, `acting` is
    the policy and learning runs where it is called."""

    def __init__(self, policy: EmmaPolicy, overlap: bool, thread_name: str) -> None:
        self.policy = policy
        self.acting = copy.deepcopy(policy).eval() if overlap else policy
        self._pool = ThreadPoolExecutor(1, thread_name_prefix=thread_name) if overlap else None
        self._learning: Future | None = None

    def learn(self, fn: Callable[..., object], *args) -> None:
        """fn(*args), the learning of a round: here, or overlapped, after the last round's learning
        ended, in the learning thread."""
        if self._pool is None:
            fn(*args)
            return
        self.wait()
        self._learning = self._pool.submit(fn, *args)

    def wait(self) -> bool:
        """Wait for the round being learnt, if any (re-raising what failed in it), and give the
        acting copy its weights; True when there was one."""
        if self._learning is None:
            return False
        learning, self._learning = self._learning, None
        learning.result()
        self.acting.load_state_dict(self.policy.state_dict())
        return True

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)


def online_imitation(
    policy: EmmaPolicy,
    imaginer,
    policy_manual: ManualBatch | Callable[[], ManualBatch],
    label_round: RoundLabeller,
    first_obs: np.ndarray,
    budget: Budget,
    seed: int = 0,
    max_steps: int = 32,
    labelled: LabelledSet | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    on_round: Callable[[int, float, int], None] | None = None,
    timings: dict[str, float] | None = None,
) -> list[float]:
    """Online imitation inside the world model, DAgger style: each round the learner imagines
    `budget.episodes` trajectories (sampling) through `imaginer` (a ServiceImaginer or
    LocalImaginer) from starts drawn from first_obs ([4, 3] or [k, 4, 3]), the reviewer labels the
    round's states (label_round), and the policy takes `budget.grad_steps` minibatch steps on every
    state labelled so far (`labelled`, which the caller may keep across feedback). Returns the mean
    loss of each round. policy_manual may be a callable, read each round (a new manual mid-way).
    `timings`, when given, accumulates the seconds spent imagining, labelling, fitting and (with
    budget.overlap) waiting for the learning thread.
    """
    starts = np.asarray(first_obs, dtype=np.uint8).reshape(-1, 4, 3)
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(policy.parameters(), lr=budget.lr)
    labelled = labelled if labelled is not None else LabelledSet()
    timings = timings if timings is not None else {}
    losses: list[float] = []
    behind = LearningBehind(policy, budget.overlap, "imitation-fit")

    def spend(what: str, since: float) -> float:
        now = time.perf_counter()
        timings[what] = timings.get(what, 0.0) + now - since
        return now

    def learn(im: Imagination, u: int, manual: ManualBatch) -> None:
        began = time.perf_counter()
        labelled.add(*label_round(im, u + 1))
        began = spend("label", began)
        if len(labelled) == 0:
            return
        h, y = labelled.arrays()
        round_losses = fit_labels(
            policy, manual, h, y, budget.grad_steps, budget.lr, budget.batch, seed * 10_000 + u, opt, should_stop
        )
        spend("fit", began)
        if not round_losses:  # stopped before its first step
            return
        losses.append(float(np.mean(round_losses)))
        if on_round is not None:
            on_round(u + 1, losses[-1], len(labelled))

    def finish_learning() -> None:
        began = time.perf_counter()
        if behind.wait():
            spend("wait", began)

    try:
        for u in range(budget.iterations):
            if should_stop():
                break
            manual = policy_manual() if callable(policy_manual) else policy_manual
            began = time.perf_counter()
            im = imagine_round(
                behind.acting, imaginer, manual, starts, budget.episodes, rng, gen, seed * 10_000 + u, max_steps,
                budget.constrained,
            )  # fmt: skip
            spend("imagine", began)
            if budget.overlap:
                finish_learning()
                if should_stop():  # the last round's learning asked to stop (e.g. no labels came)
                    break
            behind.learn(learn, im, u, manual)
        finish_learning()
    finally:
        behind.close()
    return losses


def online_imitation_with(
    policy: EmmaPolicy,
    world: WorldModel,
    world_manual: ManualBatch,
    policy_manual: ManualBatch,
    labeller: Callable[[np.ndarray, int], np.ndarray],
    first_obs: np.ndarray,
    budget: Budget,
    seed: int = 0,
    max_steps: int = 32,
) -> list[float]:
    """Online imitation in a world model of this process, labelled by `labeller`
    (observations [n, 4, 3], t) -> actions (the simulated human): Table 3's setting."""
    from .imaginer import LocalImaginer

    return online_imitation(
        policy,
        LocalImaginer(world, world_manual),
        policy_manual,
        expert_rounds(labeller, max_steps),
        first_obs,
        budget,
        seed,
        max_steps,
    )

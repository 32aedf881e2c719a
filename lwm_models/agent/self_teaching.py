"""Learning from the manual alone, and asking a person only what the world model left open.

Table 3's online imitation needs a reviewer who labels every imagined state (about 8,000 labels a
game). Here the agent labels its imagined states itself: the world model, which has read the
manual, is asked what touching each entity does (lwm_models/agent/roles.py), and the expert of
the paper's simulated human (go to the message, then the goal) labels each
state under those roles, weighted by how sure the world model is of them. The rest is online
imitation as in Table 3: the policy acts in imagination, its states are labelled, it learns from
every state labelled so far (DAgger).

A person is asked only where it matters: the states on which the role assignments still in play
would act differently (query by committee, the committee being the six assignments weighted by
the belief). Each answer moves the belief, and every self-made label is made again under the new
belief, so a few answers correct all the labels a wrong belief made. With a world model that read
the manual clearly the belief is sure and nothing is asked.

A world model that misreads the manual can be confidently wrong: its belief is trusted only so far
(roles.TRUST), so that it still asks, and a person's first few answers are what shows it.

With `Teaching.overlap` the policy learns from round u while round u+1 is imagined by the policy
as it was before that learning (a round behind). On the real system the two run on two cores: the
world-model server imagines while the planner learns.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import torch

from ..world.base import ManualBatch
from .learning import LearningBehind, fit_labels, imagine_round, imagined_states
from .policy import EmmaPolicy
from .roles import RoleBelief, believe

Ask = Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int], np.ndarray]
"""ask(histories [k, 3, 4, 3], observations [k, 4, 3], steps [k] (0 = the start), imagined
trajectories [k], round) -> the reviewer's actions [k], or -1 where they gave none."""


@dataclass
class Teaching:
    """What self-teaching in one game may spend, and how much it may ask of a person."""

    rounds: int = field(default=10, metadata={"help": "rounds of imagination with the current policy"})
    episodes: int = field(default=32, metadata={"help": "imagined episodes per round"})
    grad_steps: int = field(default=20, metadata={"help": "minibatch steps after each round"})
    # 64, not Table 3's 256: the same real return on Table 3's 30 NewAll games (manual alone, and 10
    # labels) in less than half the wait (docs/speed.md, "Learning").
    batch: int = field(default=64, metadata={"help": "labelled states per minibatch step"})
    lr: float = field(default=1e-3, metadata={"help": "Adam learning rate of the policy"})
    contact_samples: int = field(
        default=8, metadata={"help": "imagined trajectories per ordering of two entities, to read the roles"}
    )
    label_budget: int = field(default=0, metadata={"help": "labels a person may be asked for in all (0: none)"})
    per_round: int = field(
        default=5, metadata={"help": "labels asked at most in one round (the belief moves between rounds)"}
    )
    ask_above: float = field(
        default=0.05, metadata={"help": "ask about a state only when the belief's assignments disagree this much"}
    )
    constrained: bool = field(default=False, metadata={"help": "imagine under the game's rules"})
    # On: the same real return on Table 3's 30 NewAll games (manual alone, and 10 labels), paired with
    # the rounds in turn, and a third less wait on the real system (docs/speed.md, "Imagining while
    # learning").
    overlap: bool = field(
        default=True,
        metadata={
            "help": "imagine round u+1 while the policy learns from round u (round u+1 acts with the policy "
            "a round behind)"
        },
    )
    fill: bool = field(
        default=False,
        metadata={
            "help": "every round asks per_round states (a person who chose to teach): where the roles are in "
            "doubt first, then where the policy is least sure"
        },
    )


@dataclass
class TeachingResult:
    belief: RoleBelief
    asked: int = 0  # labels the person was asked for
    answered: int = 0  # labels they gave
    rounds: int = 0
    self_labelled: int = 0  # states the agent labelled itself
    seconds: dict[str, float] = field(default_factory=dict)
    taught: tuple[np.ndarray, np.ndarray] | None = None  # (histories, actions) the reviewer labelled

    def summary(self) -> dict:
        assignment, p = self.belief.best()
        return {
            "roles": self.belief.describe(),
            "assignment": list(assignment),
            "p": round(p, 4),
            "asked": self.asked,
            "answered": self.answered,
            "rounds": self.rounds,
            "self_labelled": self.self_labelled,
            "seconds": {k: round(v, 2) for k, v in self.seconds.items()},
        }


def choose_questions(belief: RoleBelief, obs: np.ndarray, k: int, above: float) -> np.ndarray:
    """Indices of at most k states worth asking about: those on which the belief's assignments
    disagree most, above `above`; distinct observations only (the same board asked twice is a
    waste of the person's time)."""
    if k <= 0 or not len(obs):
        return np.zeros(0, dtype=np.int64)
    score = belief.doubt(obs)
    chosen, seen = [], set()
    for i in np.argsort(-score, kind="stable"):
        if score[i] < above or len(chosen) == k:
            break
        key = obs[i].tobytes()
        if key not in seen:
            seen.add(key)
            chosen.append(int(i))
    return np.asarray(chosen, dtype=np.int64)


def _with_unsure(
    policy: EmmaPolicy, manual: ManualBatch, hist: np.ndarray, obs: np.ndarray, chosen: np.ndarray, k: int
) -> np.ndarray:
    """`chosen`, filled up to k with the distinct states where the policy's favourite action is
    least probable."""
    with torch.no_grad():
        logits = policy(
            torch.from_numpy(np.ascontiguousarray(hist)), policy.id_values(manual).expand(len(hist), -1, -1)
        )
    sure = torch.softmax(logits, -1).max(-1).values.numpy()
    out, seen = list(chosen), {obs[i].tobytes() for i in chosen}
    for i in np.argsort(sure, kind="stable"):
        if len(out) == k:
            break
        if obs[i].tobytes() not in seen:
            seen.add(obs[i].tobytes())
            out.append(int(i))
    return np.asarray(out, dtype=np.int64)


def teach(
    policy: EmmaPolicy,
    imaginer,
    policy_manual: ManualBatch | Callable[[], ManualBatch],
    starts: np.ndarray,
    config: Teaching,
    ask: Ask | None = None,
    seed: int = 0,
    belief: RoleBelief | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    on_round: Callable[[int, TeachingResult], None] | None = None,
) -> TeachingResult:
    """Teach `policy` in imagination from the world model's reading of the manual, asking `ask`
    (a person, or the scripted reviewer) for at most `config.label_budget` labels.

    starts: the game's first boards [k, 4, 3]; `belief`: a belief to start from (else the world
    model's, read through `imaginer` now)."""
    starts = np.asarray(starts, dtype=np.uint8).reshape(-1, 4, 3)
    seconds: dict[str, float] = {}

    def spend(what: str, since: float) -> float:
        now = time.perf_counter()
        seconds[what] = seconds.get(what, 0.0) + now - since
        return now

    began = time.perf_counter()
    if belief is None:
        belief = believe(imaginer, starts, config.contact_samples, seed)
    began = spend("roles", began)
    result = TeachingResult(belief, seconds=seconds)
    if on_round is not None:
        on_round(0, result)  # what the world model read, before any round: a person hears it first
    rng = np.random.default_rng(seed)
    gen = torch.Generator().manual_seed(seed)
    opt = torch.optim.Adam(policy.parameters(), lr=config.lr)
    own_hist, own_obs, own_steps = [], [], []  # states the agent labels itself (again, each round)
    own_labels: list[np.ndarray] = []  # their labels under the belief as it was last
    their_hist, their_labels = [], []  # states the person labelled
    behind = LearningBehind(policy, config.overlap, "teaching-fit")
    try:
        for u in range(config.rounds):
            if should_stop():
                break
            manual = policy_manual() if callable(policy_manual) else policy_manual
            began = time.perf_counter()
            im = imagine_round(
                behind.acting, imaginer, manual, starts, config.episodes, rng, gen, seed * 10_000 + u, 32,
                config.constrained,
            )  # fmt: skip
            hist, obs, steps, traj = imagined_states(im, 32)
            began = spend("imagine", began)

            keep = np.ones(len(obs), dtype=bool)
            moved = False  # whether a person's answer moved the belief this round
            room = min(config.per_round, config.label_budget - result.asked)
            if ask is not None and room > 0:
                chosen = choose_questions(belief, obs, room, config.ask_above)
                if config.fill and len(chosen) < room:
                    chosen = _with_unsure(behind.acting, manual, hist, obs, chosen, room)
                if len(chosen):
                    asked = ask(hist[chosen], obs[chosen], steps[chosen], traj[chosen], u + 1)
                    answers = np.asarray(asked, dtype=np.int64)
                    result.asked += len(chosen)
                    given = answers >= 0
                    result.answered += int(given.sum())
                    if given.any():
                        at = chosen[given]
                        belief.update(obs[at], answers[given])
                        moved = True
                        their_hist.append(hist[at])
                        their_labels.append(answers[given])
                        keep[at] = False
                began = spend("ask", began)
            own_hist.append(hist[keep])
            own_obs.append(obs[keep])
            own_steps.append(steps[keep])

            # Every self-made label is made again under the belief as it is now. A label depends
            # on its state and the belief alone, so while no answer moves the belief, the earlier
            # rounds' labels stand and only the new round's states are labelled.
            if moved:
                own_labels = [belief.labels(o, s + 1, seed) for o, s in zip(own_obs[:-1], own_steps[:-1])]
            own_labels.append(belief.labels(own_obs[-1], own_steps[-1] + 1, seed))
            labels = np.concatenate(own_labels)
            h = np.concatenate(own_hist + their_hist)
            y = np.concatenate([labels, *their_labels]).astype(np.int64)
            began = spend("label", began)
            # Overlapped, what the last round's learning did not hide behind this round counts as fitting.
            behind.learn(
                fit_labels, policy, manual, h, y, config.grad_steps, config.lr, config.batch, seed * 10_000 + u, opt,
                should_stop,
            )  # fmt: skip
            spend("fit", began)
            result.rounds = u + 1
            result.self_labelled = len(labels)
            if on_round is not None:
                on_round(u + 1, result)
        began = time.perf_counter()
        if behind.wait():
            spend("fit", began)
    finally:
        behind.close()
    if their_labels:
        result.taught = (np.concatenate(their_hist), np.concatenate(their_labels))
    return result


__all__ = ["Ask", "Teaching", "TeachingResult", "choose_questions", "teach"]

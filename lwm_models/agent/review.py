"""The review loop, ROS-free: what the planner node does, as a state machine with one worker.

A review is one real episode. It opens when the episode's first state and the world-model server's manual
for that game are both known, and goes through these phases:

    planning  -> reviewing -> (feedback) -> planning ... -> executing -> done
                    |  imitate: teaching rounds (label requests of a few states out, labels in)
                    |  abort: done, nothing executed
    executing -> (the world model, from the real state, gives death a share the plan did not
                  show) -> planning from the real state -> reviewing -> executing (resumed)

Events arrive from any thread (the node's callbacks): `on_status` (the world-model server's manual and its
version), `on_state` (the real game), `on_feedback`, `on_labels`. They validate at once, raising
FeedbackError for input that does not fit (the node reports it; nothing changes), and hand the
slow work (imagining through the world-model server, learning, acting in the real game) to one worker
thread, in order. The loop talks to the outside only through `Ports` and the imaginer, so the
same code runs under ROS and in process.

Every manual version, plan, feedback, label batch, saved policy and report goes to the ledger as
it happens; a planner restarted mid-review rebuilds the review from it (`_resume`).
"""

from __future__ import annotations

import queue
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from safetensors.numpy import load_file as load_arrays
from safetensors.numpy import save_file as save_arrays

from ..data.episode import Episode, game_of
from ..errors import LwmError
from ..ledger import Ledger
from .agent import Correction, FeedbackError, Plan, PlanReviewAgent, start_observations_like
from .imaginer import Unavailable
from .learning import Budget, LabelledSet
from .policy import EmmaPolicy, load_policy, save_policy
from .self_teaching import Teaching
from .undo import UNDO_SOURCE, last_change, policy_before

LABELS = "labels.safetensors"  # beside a review's policy snapshot: the states labelled so far
MAX_EARLY = 100  # feedback and labels kept while no review is open (a restarted planner)


def check_labels(request: dict, states: list[int], actions: list[int]) -> None:
    """FeedbackError unless `states` and `actions` label states of `request`, each once. The planner
    checks what it takes; a human node checks the same before it signs, so a person hears why at once."""
    if len(states) != len(actions):
        raise FeedbackError(f"{len(states)} states but {len(actions)} actions: give one action per state")
    shown = len(request["observations"])
    bad = [s for s in states if not 0 <= s < shown]
    if bad:
        raise FeedbackError(f"state {bad[0]} was never shown (request {request['request_id']} has {shown} states)")
    if len(set(states)) != len(states):
        raise FeedbackError("a state is labelled twice")


# What taking each decision does, said to its sender.
TAKEN = {
    "approve": "plan {plan} approved: the agent now acts in the real game",
    "reject": "plan {plan} rejected: the agent imagines a new plan",
    "corrections": "corrections of plan {plan} taken: the agent learns them and re-plans",
    "imitate": "teaching started on plan {plan}: the agent asks about the states it is unsure of",
    "demonstrations": "demonstrations taken: the agent learns them and re-plans",
    "abort": "plan {plan} aborted: nothing is executed",
}
STOP_TAKEN = "teaching stops now: the agent keeps what it has learnt and re-plans"
STOP_EXECUTION_TAKEN = "the agent stops playing before its next move: a report of what it did follows"


WORSE_AFTER = ("corrections", "imitation", "demonstrations", "manual")  # the changes a person can take back
WORSE_DEATHS = 0.25  # this much more of the sampled futures die (2 of the default 8) ...
WORSE_RETURN = 0.5  # ... or their mean return falls this much: the plan looks worse


def worse_than(before: Plan, plan: Plan) -> dict | None:
    """Whether `plan` looks worse than `before` by its sampled futures; what `before` scored, if so.
    The futures, not the one trajectory shown, since a single sample's end is noise."""
    was, now = before.futures, plan.futures
    if (
        now["death_share"] - was["death_share"] >= WORSE_DEATHS
        or was["return_mean"] - now["return_mean"] >= WORSE_RETURN
    ):
        return {"plan": before.plan_id, "death_share": was["death_share"], "return_mean": was["return_mean"]}
    return None


@dataclass
class ReviewConfig:
    """How the planner reviews. Before the first plan under each manual the agent teaches itself
    from the manual alone (`teaching`, lwm_models/agent/self_teaching.py); a reviewer who
    chooses to teach ("imitate") is asked about `teaching.per_round` states a round."""

    futures: int = 8  # sampled futures of the policy shown with each plan
    max_steps: int = 32  # the game's time limit
    correction_updates: int = 30  # minibatch steps after corrections
    teaching: Teaching = field(default_factory=Teaching)  # rounds 0: no learning from the manual alone
    budget: Budget = field(default_factory=Budget)  # demonstrations (filtered BC)
    clone_updates: int = 400  # filtered BC: steps on the reviewer's demonstrations (Table 3: 40 x 10)
    label_timeout: float = 120.0  # seconds to wait for a round's labels; imitation ends without them
    risk_threshold: float = 0.5  # execution stops when this share of imagined futures die ...
    risk_horizon: int = 3  # ... within this many steps of the real state, and the plan did not show it
    risk_samples: int = 8
    max_rereviews: int = 2  # reviews asked again during one execution
    env_retry_for: float = 60.0  # seconds to wait for the environment's services


@dataclass
class Ports:
    """The loop's way out: publishers and the real game's services (raise Unavailable when down)."""

    publish_plan: Callable[[dict], None]
    publish_label_request: Callable[[dict], None]
    publish_report: Callable[[dict], None]
    env_reset: Callable[[dict], dict]
    env_step: Callable[[dict], dict]
    log: Callable[[str], None] = print
    # while the agent teaches itself, each round (a progress payload): a person waits for the plan
    publish_progress: Callable[[dict], None] = lambda payload: None


@dataclass
class Execution:
    """The real episode as the approved policy plays it (kept while a review is asked again)."""

    seed: int
    observations: list = field(default_factory=list)
    actions: list = field(default_factory=list)
    rewards: list = field(default_factory=list)
    plans: list = field(default_factory=list)
    planned: list = field(default_factory=list)  # the first approved plan's observations
    risk_steps: list = field(default_factory=list)
    reviews_asked: int = 0
    outcome: str = "running"


@dataclass
class Review:
    review_id: str
    seed: int
    game: str
    first_obs: np.ndarray
    agent: PlanReviewAgent
    phase: str = "planning"
    plan: Plan | None = None
    plans: int = 0
    revisions: int = 0
    requests: int = 0
    answered: set = field(default_factory=set)  # (plan_id, decision) taken
    labelled_requests: set = field(default_factory=set)  # label requests whose labels were taken
    request: dict | None = None  # the label request waiting for labels
    labels: tuple | None = None
    labels_in: threading.Event = field(default_factory=threading.Event)
    execution: Execution | None = None
    learned: dict = field(default_factory=lambda: {"corrections": 0, "imitation_rounds": 0, "demonstrations": 0})
    teaching: bool = False  # an online imitation is under way (a "stop" ends it)
    stop_teaching: threading.Event = field(default_factory=threading.Event)
    stop_execution: threading.Event = field(default_factory=threading.Event)  # a "stop" while executing


class ReviewLoop:
    def __init__(
        self,
        make_policy: Callable[[], EmmaPolicy],
        encoder,
        imaginer,
        ports: Ports,
        ledger: Ledger,
        config: ReviewConfig | None = None,
        policy_dir: str | Path | None = None,
    ) -> None:
        self.make_policy = make_policy
        self.encoder = encoder
        self.imaginer = imaginer
        self.ports = ports
        self.ledger = ledger
        self.config = config or ReviewConfig()
        self.policy_dir = Path(policy_dir) if policy_dir else ledger.path.parent / "policies"
        self.lock = threading.RLock()
        self.manual: list[str] | None = None
        self.manual_version = 0
        self.manual_game = ""
        self.manual_source = ""
        self.manual_facts: list[dict] = []  # what the person stated with the manual (answers)
        self.pending_state: dict | None = None
        self.review: Review | None = None
        self.early: list[tuple[Callable[[dict], None], dict]] = []  # arrived before any review opened
        self.agents: dict[str, PlanReviewAgent] = {}  # what was learned, per game
        self.jobs: queue.Queue = queue.Queue()
        self.closing = threading.Event()
        self.worker = threading.Thread(target=self._work, name="review-worker", daemon=True)
        self.worker.start()

    # ================================================================== events
    def on_status(self, status: dict) -> None:
        """The world-model server's manual: a new version re-plans the review under it."""
        if "manual" not in status:
            return
        with self.lock:
            if status["manual_version"] == self.manual_version and status["manual"] == self.manual:
                return
            self.manual, self.manual_version = list(status["manual"]), int(status["manual_version"])
            self.manual_facts = list(status.get("facts", []))
            self.manual_game = status.get("game", "")
            self.manual_source = status.get("manual_source", "")
            r = self.review
            if r is not None and r.phase != "done" and self._manual_fits(r.game):
                r.agent.set_manual(self.manual, self.manual_facts)
                self._record_manual(r)
                if r.phase == "reviewing":
                    r.phase = "planning"
                    r.revisions += 1
                    self._submit(lambda: self._plan(r, "manual"))
            self._maybe_start()

    def on_state(self, state: dict) -> None:
        """The real game: an episode's first state (t = 0) opens its review."""
        if state["t"] != 0:
            return
        with self.lock:
            r = self.review
            if r is not None and (r.review_id == state["episode_id"] or r.phase == "executing"):
                return
            self.pending_state = state
            self._maybe_start()

    def on_feedback(self, msg: dict) -> str:
        """Take a reviewer's answer to the plan under review; returns what taking it does (for the
        sender's acknowledgement). FeedbackError, with the reason, when it cannot be taken."""
        with self.lock:
            if self._keep_early(self.on_feedback, msg):
                return f"kept until review {msg['review_id']} opens (the planner is starting)"
            r = self.review
            if r is None or msg["review_id"] != r.review_id:
                current = None if r is None else r.review_id
                raise FeedbackError(f"feedback for review {msg['review_id']!r}; the open review is {current!r}")
            decision = msg["decision"]
            if (msg["plan_id"], decision) in r.answered:
                return f"{decision} of plan {msg['plan_id']} was taken already"  # delivered again after a restart
            if decision == "stop":
                return self._stop(r, msg)
            if r.phase == "done":
                raise FeedbackError(
                    f"review {r.review_id} is over (its report is out); start the next episode to review again"
                )
            if r.phase != "reviewing" or r.plan is None or msg["plan_id"] != r.plan.plan_id:
                raise FeedbackError(
                    f"plan {msg['plan_id']} is not under review (plan {r.plan and r.plan.plan_id}, {r.phase})"
                )
            taken = TAKEN.get(decision, "").format(plan=msg["plan_id"])
            if decision == "undo":
                change = last_change(self.ledger.history(r.review_id))
                if change.kind == "manual":
                    raise FeedbackError(
                        f"your newest change is {change.words()}, which the world-model server holds: it is taken "
                        "back by sending the manual before it again (u at the terminal, undo on the page)"
                    )
                taken = f"{change.words()} taken back: the agent returns to what it knew before and re-plans"
            elif decision == "corrections":
                r.agent.check_corrections(r.plan, [Correction(c["step"], c["action"]) for c in msg["corrections"]])
            elif decision == "demonstrations":
                for i, d in enumerate(msg["demonstrations"]):
                    if len(d["observations"]) != len(d["actions"]) + 1:
                        raise FeedbackError(f"demonstration {i}: give one action fewer than observations")
            record = self.ledger.record(r.review_id, "feedback", msg)
            r.answered.add((msg["plan_id"], decision))
            r.phase = "executing" if decision == "approve" else "done" if decision == "abort" else "planning"
            self._submit(lambda: self._take(r, msg, record))
            return taken

    def _stop(self, r: Review, msg: dict) -> str:
        """End the long job under way (called with the lock held). Teaching: the round waiting for
        labels ends without them, no new round starts, and the agent re-plans with what it learnt
        so far. Execution: the agent makes no further move in the real game and reports."""
        if r.phase == "executing":
            self.ledger.record(r.review_id, "feedback", msg)
            r.answered.add((msg["plan_id"], "stop"))
            r.stop_execution.set()
            return STOP_EXECUTION_TAKEN
        if not r.teaching:
            raise FeedbackError("there is nothing under way to stop (no teaching, no execution)")
        self.ledger.record(r.review_id, "feedback", msg)
        r.answered.add((msg["plan_id"], "stop"))
        r.stop_teaching.set()
        r.labels_in.set()  # the round waiting for labels ends now
        return STOP_TAKEN

    def on_labels(self, msg: dict) -> str:
        """Take the labels of the open label request; returns what was taken."""
        with self.lock:
            if self._keep_early(self.on_labels, msg):
                return f"kept until review {msg['review_id']} opens (the planner is starting)"
            r = self.review
            if r is None or msg["review_id"] != r.review_id:
                raise FeedbackError(f"labels for review {msg['review_id']!r}, which is not open")
            req = r.request
            if req is None or msg["request_id"] != req["request_id"]:
                if msg["request_id"] in r.labelled_requests:  # delivered again after a restart
                    return f"labels for request {msg['request_id']} were taken already"
                if msg["request_id"] <= r.requests:
                    raise FeedbackError(
                        f"label request {msg['request_id']} is over: its time ran out before these labels came, "
                        f"so nothing was learnt from them"
                    )
                raise FeedbackError(f"no label request {msg['request_id']} (the last is {r.requests})")
            states, actions = msg["states"], msg["actions"]
            check_labels(req, states, actions)
            signed = {k: msg[k] for k in ("reviewer", "signed_at", "nonce") if k in msg}  # who, and the replay guard
            record = {"request_id": req["request_id"], "labels": len(states), **signed}
            self.ledger.record(r.review_id, "labels", record)
            r.labelled_requests.add(req["request_id"])
            r.labels = (np.asarray(states, dtype=np.int64), np.asarray(actions, dtype=np.int64))
            r.request = None
            r.labels_in.set()
            return f"{len(states)} label(s) for request {msg['request_id']} taken"

    def _keep_early(self, handler: Callable[[dict], None], msg: dict) -> bool:
        """A restarted planner gets the kept feedback and labels before its review is rebuilt:
        keep them (up to MAX_EARLY) for the review to take when it opens."""
        if self.review is None and len(self.early) < MAX_EARLY:
            self.early.append((handler, msg))
            return True
        return False

    def close(self, wait: float = 5.0) -> None:
        """Stop taking work; wait up to `wait` seconds for the job in hand (a node that is ending
        its process waits briefly: what it abandons, the ledger lets a restart resume)."""
        self.closing.set()
        with self.lock:
            if self.review is not None:
                self.review.labels_in.set()
        self.jobs.put(None)
        self.worker.join(timeout=wait)

    # ================================================================== starting
    def _manual_fits(self, game: str) -> bool:
        return not self.manual_game or self.manual_game == game

    def _maybe_start(self) -> None:
        s = self.pending_state
        if s is None or self.manual is None or not self._manual_fits(game_of(s["episode_id"])):
            return
        self.pending_state = None
        review_id = s["episode_id"]
        seed = int(s.get("seed", Episode.parse(review_id).seed))
        game = game_of(review_id)
        agent = self.agents.get(game)
        if agent is None:
            agent = PlanReviewAgent(
                self.make_policy(),
                self.encoder,
                self.imaginer,
                list(self.manual),
                self.config.max_steps,
                futures=self.config.futures,
            )
            agent.set_manual(self.manual, self.manual_facts)
            self.agents[game] = agent
        else:
            agent.set_manual(self.manual, self.manual_facts)
        r = Review(review_id, seed, game, np.asarray(s["observation"], dtype=np.uint8), agent)
        self.review = r
        history = self.ledger.history(review_id)
        if history:
            self._resume(r, history)
        else:
            # What the agent knows as the review opens (what earlier episodes of this game taught it)
            # is saved too: taking back the person's first answer returns to it.
            self._save_policy(r, self._record_manual(r))
            self._submit(lambda: self._plan(r, "start"))
        early, self.early = self.early, []
        for handler, msg in early:
            try:
                handler(msg)
            except LwmError as exc:
                self.ports.log(f"kept {msg.get('decision', 'labels')} for {msg['review_id']} not taken: {exc}")

    def _record_manual(self, r: Review) -> int:
        return self.ledger.record(
            r.review_id,
            "manual",
            {
                "manual_version": self.manual_version,
                "descriptions": self.manual,
                "source": self.manual_source,
                **({"facts": self.manual_facts} if self.manual_facts else {}),
            },  # fmt: skip
        )

    # ================================================================== the worker
    def _submit(self, job: Callable[[], None]) -> None:
        self.jobs.put(job)

    def _work(self) -> None:
        while not self.closing.is_set():
            job = self.jobs.get()
            if job is None:
                return
            try:
                job()
            except Exception as exc:  # the loop must survive one failed job; the node reports it
                self.ports.log(f"review job failed: {type(exc).__name__}: {exc}")
                with self.lock:
                    r = self.review
                    if r is not None and r.phase in ("planning", "executing") and r.plan is not None:
                        r.phase = "reviewing"  # the last plan stays open for feedback
                        self.ports.publish_plan(self._plan_message(r, r.plan, "error"))

    def _take(self, r: Review, msg: dict, record: int) -> None:
        decision = msg["decision"]
        a = r.agent
        if decision == "approve":
            self._execute(r)
            return
        if decision == "abort":
            self._report(r, aborted=True)
            return
        r.revisions += 1
        if decision == "corrections":
            fixes = [Correction(c["step"], c["action"]) for c in msg["corrections"]]
            a.correct(r.plan, fixes, self.config.correction_updates)
            r.learned["corrections"] += len(fixes)
            self._save_policy(r, record)
        elif decision == "imitate":
            self._teach(r, int(msg.get("rounds", self.config.teaching.rounds)))
            self._save_policy(r, record)
        elif decision == "demonstrations":
            a.clone(msg["demonstrations"], self.config.clone_updates)
            r.learned["demonstrations"] += len(msg["demonstrations"])
            self._save_policy(r, record)
        elif decision == "undo":
            history = [rec for rec in self.ledger.history(r.review_id) if rec["id"] < record]
            change = last_change(history)
            self._load_policy(r, policy_before(history, change))
            self._save_policy(r, record)
            self.ports.log(f"review {r.review_id}: {change.words()} taken back")
        self._plan(r, {"reject": "reject", "imitate": "imitation"}.get(decision, decision))

    # ------------------------------------------------------------------ plans
    def _start_of(self, r: Review) -> tuple[np.ndarray, int, list]:
        """Where the next plan starts: the episode's first state, or the real state of a paused
        execution (with the observations before it)."""
        ex = r.execution
        if ex is not None and ex.outcome == "running" and ex.observations:
            return np.asarray(ex.observations[-1], dtype=np.uint8), len(ex.actions), ex.observations[:-1]
        return r.first_obs, 0, []

    def _plan(self, r: Review, reason: str) -> None:
        start, start_step, before = self._start_of(r)
        previous = r.plan
        rejected = previous if reason == "reject" else None
        if reason in ("start", "manual") and self.config.teaching.rounds and r.agent.unread:
            if reason == "manual" and r.agent.confirmed(self._starts(r)):
                self.ports.log(f"review {r.review_id}: the answer confirms the roles and movements it acts on")
            else:
                self._teach_self(r, fresh=reason == "manual")
        for _ in range(3):  # a manual that changed while imagining makes the plan stale: imagine again
            with self.lock:
                r.plans += 1
                plan_id = r.plans
            plan = r.agent.make_plan(start, plan_id, r.seed * 1000 + plan_id, start_step, before)
            with self.lock:
                if plan.manual_version in (0, self.manual_version) or self.closing.is_set():
                    break
        with self.lock:
            if self.review is not r:
                return  # a newer review took over
            r.plan = plan
            r.phase = "reviewing"
            message = self._plan_message(r, plan, reason)
            if rejected is not None and list(plan.actions) == list(rejected.actions):
                # A reject changes nothing the agent has learnt, so the person must hear that the
                # "new" plan is the old one, and what can change it.
                message["repeats"] = rejected.plan_id
            undone = reason == "manual" and self.manual_source == UNDO_SOURCE
            if reason in WORSE_AFTER and previous is not None and not undone:
                worse = worse_than(previous, plan)
                if worse is not None:
                    message["worse"] = {**worse, "after": reason}
            self.ledger.record(r.review_id, "plan", message)
        self.ports.publish_plan(message)
        self.ports.log(
            f"review {r.review_id}: plan {plan.plan_id} ({reason}, manual v{plan.manual_version}): imagined "
            f"return {plan.imagined_return:+.2f}, futures die {plan.futures['death_share']:.0%}"
        )

    def _plan_message(self, r: Review, plan: Plan, reason: str) -> dict:
        belief = r.agent.belief
        return {
            **({"roles": belief.describe()} if belief is not None else {}),
            **({"questions": belief.questions} if belief is not None and belief.questions else {}),
            **({"facts": belief.facts} if belief is not None and belief.facts else {}),
            "review_id": r.review_id,
            "manual": list(r.agent.manual),
            "reason": reason,
            "constrained": bool(getattr(self.imaginer, "constrained", False)),
            "learning": {**r.learned, "labelled": len(r.agent.labelled)},
            **plan.to_json(),
        }

    # ------------------------------------------------------------------ learning
    def _starts(self, r: Review) -> np.ndarray:
        """Where imagined rounds start: the game's first boards; asked again mid-episode, half
        from the real state."""
        start, start_step, _ = self._start_of(r)
        starts = start_observations_like(r.first_obs)
        if start_step:
            starts = np.concatenate([starts, np.repeat(start[None], len(starts), 0)])
        return starts

    def _teach_self(self, r: Review, fresh: bool) -> None:
        """Learn from the manual alone, asking nobody, before the plan is shown."""
        began = time.perf_counter()
        rounds = self.config.teaching.rounds

        def progress(round_no: int, done: bool = False, **more) -> None:
            self.ports.publish_progress(
                {
                    "review_id": r.review_id,
                    "phase": "self_teaching",
                    "manual_version": self.manual_version,
                    "round": round_no,
                    "rounds": rounds,
                    "seconds": round(time.perf_counter() - began, 2),
                    "done": done,
                    **more,
                }
            )

        progress(0)
        result = r.agent.teach_self(
            self._starts(r),
            self.config.teaching,
            seed=r.seed * 1000 + r.plans,
            should_stop=lambda: self.closing.is_set() or self.review is not r,
            on_round=lambda round_no, res: progress(round_no, roles=res.belief.describe()),
            fresh=fresh,
        )
        summary = result.summary()
        progress(result.rounds, done=True, roles=summary["roles"])
        record = self.ledger.record(r.review_id, "self_teaching", summary)
        self._save_policy(r, record)
        roles = ", ".join(f"{e['identity']} {e['role']} ({e['p']:.0%})" for e in summary["roles"])
        self.ports.log(
            f"review {r.review_id}: taught itself from the manual in {time.perf_counter() - began:.1f} s "
            f"({result.rounds} rounds, {result.self_labelled} imagined states); roles as the world model read them: "
            f"{roles}"
        )

    def _teach(self, r: Review, rounds: int) -> None:
        """Teaching with the reviewer: rounds of self-teaching in which the agent asks the
        reviewer about teaching.per_round states a round: those the role assignments still in
        play disagree on, then those its policy is least sure of."""
        # The reviewer chose to teach: every round shows them states, even once the roles are settled.
        # The rounds go in turn, so that a round's answers shape the very next round: overlapped, the
        # scripted reviews needed more labels (80 a game against 60) and one of five ended without a
        # plan it approved (docs/speed.md, "Imagining while learning").
        teaching = Teaching(**{**self.config.teaching.__dict__, "rounds": rounds, "fill": True, "overlap": False})
        teaching.label_budget = rounds * teaching.per_round
        stopped = {"now": False}

        def ask(hist: np.ndarray, obs: np.ndarray, steps: np.ndarray, traj: np.ndarray, round_no: int) -> np.ndarray:
            none = np.full(len(obs), -1, dtype=np.int64)
            with self.lock:
                if r.stop_teaching.is_set():
                    return none
                r.requests += 1
                r.labels_in.clear()
                r.labels = None
                r.request = {
                    "review_id": r.review_id,
                    "request_id": r.requests,
                    "round": round_no,
                    "rounds": rounds,
                    "manual_version": self.manual_version,
                    "observations": obs.tolist(),
                    # the board a step earlier (a person judges movement from two frames)
                    "previous": [h[-2].tolist() if s > 0 else None for h, s in zip(hist, steps, strict=True)],
                    "steps": steps.tolist(),
                    "trajectories": traj.tolist(),
                    "timeout": self.config.label_timeout,
                }
                self.ledger.record(
                    r.review_id,
                    "label_request",
                    {"request_id": r.requests, "round": round_no, "rounds": rounds, "states": len(obs)},
                )
                request = r.request
            self.ports.publish_label_request(request)
            got = r.labels_in.wait(self.config.label_timeout)
            with self.lock:
                labels, r.labels, r.request = r.labels, None, None
            if r.stop_teaching.is_set():
                self.ports.log(f"review {r.review_id}: the reviewer stopped the teaching at round {round_no}")
                return none
            if not got or labels is None:
                stopped["now"] = True
                self.ports.log(f"review {r.review_id}: no labels for request {request['request_id']}; teaching ends")
                return none
            idx, actions = labels
            none[idx] = actions
            r.learned["imitation_rounds"] += 1
            return none

        began = time.perf_counter()
        with self.lock:
            r.teaching = True
            r.stop_teaching.clear()
        try:
            result = r.agent.teach_self(
                self._starts(r),
                teaching,
                ask,
                seed=r.seed * 1000 + r.plans,
                should_stop=lambda: (
                    stopped["now"] or r.stop_teaching.is_set() or self.closing.is_set() or self.review is not r
                ),
            )
        finally:
            with self.lock:
                r.teaching = False
        self.ports.log(
            f"review {r.review_id}: teaching took {time.perf_counter() - began:.1f} s, {result.asked} state(s) asked, "
            f"{result.answered} labelled, roles {result.belief.describe()}"
        )

    # ------------------------------------------------------------------ execution, closed loop
    def _env(self, call: Callable[[dict], dict], payload: dict) -> dict:
        deadline = time.monotonic() + self.config.env_retry_for
        while True:
            try:
                return call(payload)
            except Unavailable:
                if time.monotonic() > deadline or self.closing.is_set():
                    raise
                time.sleep(0.5)

    def _replay(self, ex: Execution) -> dict:
        """Bring the real game to where the execution was (a restarted environment, or a resumed
        review): its randomness is a function of the seed and the actions, so replaying them
        reproduces the episode."""
        state = self._env(self.ports.env_reset, {"seed": ex.seed})
        for a in ex.actions:
            state = self._env(self.ports.env_step, {"action": int(a)})
        if ex.observations and state["observation"] != ex.observations[-1]:
            raise LwmError("the real game did not replay to the same state")
        return state

    def _execute(self, r: Review) -> None:
        cfg = self.config
        plan = r.plan
        if r.execution is None:
            r.execution = Execution(r.seed)
        ex = r.execution
        ex.plans.append(plan.plan_id)
        if not ex.planned:
            ex.planned = plan.observations
        if not ex.observations:
            state = self._env(self.ports.env_reset, {"seed": ex.seed})
            ex.observations.append(state["observation"])
        state = None
        while len(ex.actions) < cfg.max_steps:
            if r.stop_execution.is_set():
                ex.outcome = "stopped"
                self.ports.log(f"review {r.review_id}: the reviewer stopped the execution at step {len(ex.actions)}")
                break
            action = r.agent.act(ex.observations)
            try:
                state = self._env(self.ports.env_step, {"action": action})
            except LwmError as exc:
                if "reset first" not in str(exc):
                    raise
                self._replay(ex)  # the environment lost the episode (restarted): replay, then step
                state = self._env(self.ports.env_step, {"action": action})
            ex.actions.append(action)
            ex.rewards.append(float(state["reward"]))
            ex.observations.append(state["observation"])
            if state["done"]:
                ex.outcome = state["outcome"]
                break
            t = len(ex.actions)
            k = t - plan.start_step  # this step in the plan
            shown = any(x < 0 for x in plan.rewards[k : k + cfg.risk_horizon])
            if shown or ex.reviews_asked >= cfg.max_rereviews:
                continue
            risk = r.agent.death_risk(ex.observations, cfg.risk_horizon, cfg.risk_samples, seed=r.seed * 100 + t)
            if risk >= cfg.risk_threshold:
                ex.risk_steps.append(t)
                ex.reviews_asked += 1
                self.ports.log(f"review {r.review_id}: step {t}: {risk:.0%} of imagined futures die; asking again")
                with self.lock:
                    r.phase = "planning"
                self._plan(r, "divergence")
                return  # an approval resumes this execution
        if ex.outcome == "running" and state is not None:
            ex.outcome = state.get("outcome", "time_limit")
        self._report(r)

    def _report(self, r: Review, aborted: bool = False) -> None:
        ex = r.execution or Execution(r.seed)
        plan = r.plan
        planned = np.asarray(ex.planned or plan.observations)
        real = np.asarray(ex.observations) if ex.observations else planned[:1]
        common = min(len(planned), len(real))
        differ = [t for t in range(common) if not np.array_equal(planned[t], real[t])]
        gaps = np.abs(planned[:common, 3, 1:].astype(int) - real[:common, 3, 1:].astype(int)).sum(-1)
        report = {
            "review_id": r.review_id,
            "plan_id": plan.plan_id,
            "real_return": float(sum(ex.rewards)),
            "imagined_return": float(plan.imagined_return),
            "steps": len(ex.actions),
            "outcome": "aborted" if aborted else ex.outcome,
            "divergence": {
                "first_step": differ[0] if differ else None,
                "mean_cells": float(gaps.mean()),
                "risk_steps": ex.risk_steps,
            },
            "reviews_asked": ex.reviews_asked,
            "revisions": r.revisions,
            "plans": ex.plans,
            "actions": ex.actions,
            "observations": [list(map(list, o)) for o in real.tolist()] if ex.observations else [],
            "planned_observations": planned.tolist(),
        }
        with self.lock:
            r.phase = "done"
            self.ledger.record(r.review_id, "report", report)
        self.ports.publish_report(report)
        stats = getattr(self.imaginer, "stats", None)
        self.ports.log(
            f"review {r.review_id}: {report['outcome']}, real return {report['real_return']:+.2f} "
            f"(imagined {report['imagined_return']:+.2f}), reviews asked again: {ex.reviews_asked}"
            + (
                f"; imagine calls {stats.calls}, round trip {stats.round_trip_s:.2f} s, "
                f"world-model server {stats.server_s:.2f} s, retries {stats.retries}"
                if stats is not None
                else ""
            )
        )
        with self.lock:
            self._maybe_start()

    # ------------------------------------------------------------------ the policy on disk
    def _policy_path(self, r: Review, after: int) -> Path:
        return self.policy_dir / re.sub(r"[^A-Za-z0-9_.-]", "_", r.review_id) / str(after)

    def _save_policy(self, r: Review, after: int) -> None:
        """The policy and its labelled states, in one checkpoint, so a restart resumes from them.
        Each is kept (one directory per ledger record it follows): taking back a person's answer
        returns to the one saved before it."""
        path = self._policy_path(r, after)
        labelled = r.agent.labelled

        pinned = list(r.agent.pinned.values())

        def labels(d: Path) -> None:
            arrays = {}
            if len(labelled):
                arrays["history"], arrays["labels"] = labelled.arrays()
            if pinned:  # the person's corrections, which must hold after a restart too
                arrays["pinned_history"] = np.stack([h for h, _ in pinned])
                arrays["pinned_actions"] = np.array([a for _, a in pinned], dtype=np.int64)
            if arrays:
                save_arrays(arrays, str(d / LABELS))

        save_policy(r.agent.policy, path, {"review_id": r.review_id, "after": after}, also=labels)
        self.ledger.record(
            r.review_id,
            "policy",
            {"path": str(path), "after": after, "labelled": len(r.agent.labelled), "learned": dict(r.learned)},
        )

    def _load_policy(self, r: Review, saved: dict | None) -> None:
        """Return the agent to a saved policy with its labelled states and pinned corrections."""
        if saved is None or not Path(saved["path"]).is_dir():
            raise LwmError(f"the policy to return to is gone ({saved and saved['path']})")
        r.agent.policy.load_state_dict(load_policy(saved["path"]).state_dict())
        data = Path(saved["path"]) / LABELS
        r.agent.labelled = LabelledSet()
        r.agent.pinned.clear()
        if data.is_file():
            arrays = load_arrays(str(data))
            if "history" in arrays:
                r.agent.labelled.add(arrays["history"], arrays["labels"])
            for h, a in zip(arrays.get("pinned_history", []), arrays.get("pinned_actions", []), strict=True):
                r.agent.pinned[h.tobytes()] = (h, int(a))
        if "learned" in saved:
            r.learned = dict(saved["learned"])

    # ------------------------------------------------------------------ resume
    def _resume(self, r: Review, history: list[dict]) -> None:
        """Rebuild a review from its ledger: the last saved policy, the last plan, what was
        answered; then redo what was interrupted (learning without a newer plan, an approved plan
        without a report: the episode is replayed from its seed)."""
        last_plan, pending, saved, done = None, None, None, False
        for rec in history:
            p, kind = rec["payload"], rec["kind"]
            if kind == "plan":
                last_plan, pending = p, None
                r.plans = max(r.plans, p["plan_id"])
            elif kind == "feedback":
                r.answered.add((p["plan_id"], p["decision"]))
                if p["decision"] == "stop":
                    # It ended a teaching (whose own feedback is what to redo) or an execution,
                    # which, redone, stops before its first move.
                    if pending is not None and pending[1]["decision"] == "approve":
                        r.stop_execution.set()
                    continue
                pending = (rec["id"], p)
                if p["decision"] not in ("approve", "abort"):
                    r.revisions += 1
            elif kind == "label_request":
                r.requests = max(r.requests, p["request_id"])
            elif kind == "labels":
                r.labelled_requests.add(p["request_id"])
            elif kind == "policy":
                saved = p
            elif kind == "report":
                done = True
        if saved is not None and Path(saved["path"]).is_dir():
            self._load_policy(r, saved)
        if done:
            # A finished review is never redone: its report is shown again, so that a person who
            # continues a run sees how this episode ended (the next episode is theirs to start).
            r.phase = "done"
            report = next(rec["payload"] for rec in reversed(history) if rec["kind"] == "report")
            self.ports.publish_report(report)
            self.ports.log(f"review {r.review_id} finished earlier ({report['outcome']}); its report is shown again")
            return
        self.ports.log(f"review {r.review_id} resumed from the ledger at plan {last_plan and last_plan['plan_id']}")
        if last_plan is None:
            self._submit(lambda: self._plan(r, "resume"))
            return
        r.plan = Plan(**{k: last_plan[k] for k in Plan.__dataclass_fields__ if k in last_plan})
        if pending is None:
            r.phase = "reviewing"
            self.ports.publish_plan(last_plan)
            return
        record, msg = pending
        if saved is not None and saved.get("after") == record:  # learned already; only the plan is missing
            r.phase = "planning"
            self._submit(lambda: self._plan(r, "resume"))
            return
        r.phase = "executing" if msg["decision"] == "approve" else "planning"
        if msg["decision"] == "approve" and r.plan.start_step > 0:
            r.plan.start_step = 0  # the paused execution is gone: the episode is played again from its start
        self._submit(lambda: self._take(r, msg, record))


__all__ = ["Execution", "Ports", "Review", "ReviewConfig", "ReviewLoop", "check_labels"]

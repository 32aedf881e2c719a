"""The world-model server: the one owner of the world model, the current manual and its version.

This is the ROS-free engine behind the world-model server node (and anything else that serves
`/lwm/imagine`). It answers imagine requests (msgs_json/imagine_request), by `op`:
- `imagine` (the default): one-shot, batched; each trajectory replays its action sequence (or
  random actions) from its start observation;
- `open` / `step` / `close`: a step-wise imagination session, for a policy that acts inside
  imagination from elsewhere (the planner). The session's KV cache stays here between steps, so a
  step costs one block of tokens, not the whole prefix. A session reads the manual that was
  current when it opened and says which version that was.

Manuals: the server keeps one per agent it serves (a fleet's agents share the model and its
batches, not necessarily the manual); a manual goes to one agent or to all. Each replacement that
changes an agent's text is a new version of its manual; the state (per agent: manual, version,
source, game) is written atomically to `state_path` when given, so a restarted world-model server
keeps counting from where it was instead of handing out version 1 again.
"""

from __future__ import annotations

import itertools
import json
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from .. import messages
from ..data.episode import game_of
from ..errors import LwmError
from ..messenger.constants import ID_TO_IDENTITY, IDENTITIES
from .base import Conditioning
from .checkpoint import load_checkpoint
from .continuous import OneShot, run_alone
from .frozen_text import FrozenTextEncoder
from .hedged_reading import code_fields
from .imagine import Imagination, StepwiseImagination, board_of, condition_rows
from .manual import ManualBatch
from .manual_reading import check_fact
from .reading import grounding, read_identities, ungrounded_note, unsure_fields, unsure_note
from .shipped import SYSTEM_WORLD_MODEL, shipped_checkpoint


class RequestError(LwmError, ValueError):
    """An imagine request the world-model server cannot serve (a bad state, an unknown session, ...)."""


@dataclass
class Session:
    rollout: StepwiseImagination
    manual_version: int
    last_used: float = field(default_factory=time.monotonic)


@dataclass
class ManualState:
    """One agent's manual as the server holds it: the text, what the world model read in it, the
    version (each change a new one) and where it came from. A fleet's agents each have one, so
    that a manual can go to one agent or to all of them."""

    manual: list[str] | None = None
    reading: list[str | None] | None = None  # the identity the model reads each description as about
    unsure: list[dict] | None = None  # per description, what its words leave unclear (reading.unsure_fields)
    version: int = 0
    source: str = ""
    game: str = ""  # split:index of the last environment manual
    # When the person signed the newest manual taken (Unix time; 0: none yet): a manual signed
    # earlier is an old one delivered again (a latched topic after a restart).
    signed_at: float = 0.0
    batch: ManualBatch | None = None
    cond: Conditioning | None = None  # the model's conditioning on `batch` as read on a board
    cond_words: tuple = ()  # the words `cond` read (a grounding model's depend on the board)

    @property
    def facts(self) -> list[dict]:
        """What the person stated with the manual (answers), held for sure: the manual's own."""
        return [] if self.batch is None else list(self.batch.facts)

    def to_json(self) -> dict:
        return {"manual": self.manual, "version": self.version, "source": self.source, "game": self.game,
                "facts": self.facts, "signed_at": self.signed_at}  # fmt: skip


class WorldModelServer:
    """agents: the agents whose manuals the server keeps (their ROS namespaces without slashes);
    the default, one unnamed agent, is the single-agent system. A request names its agent
    (`agent`), or is served under the first one's manual."""

    def __init__(
        self,
        checkpoint: str | Path | None = None,
        encoder: FrozenTextEncoder | None = None,
        state_path: str | Path | None = None,
        max_sessions: int = 32,
        session_ttl: float = 300.0,
        agents: Sequence[str] = ("",),
    ) -> None:
        self.checkpoint = Path(checkpoint) if checkpoint else shipped_checkpoint(SYSTEM_WORLD_MODEL)
        self.model, self.config = load_checkpoint(self.checkpoint)
        self.kind = self.config["kind"]
        if self.model.needs_parse:
            raise LwmError(f"the server serves models that read manuals as text; {self.kind} needs true parses")
        self.encoder = encoder if encoder is not None else self.model.frozen_text_encoder()
        if not agents or len(set(agents)) != len(agents):
            raise LwmError(f"the server needs one or more distinct agents, got {list(agents)}")
        self.agents: dict[str, ManualState] = {agent: ManualState() for agent in agents}
        self.default_agent = agents[0]
        self.state_path = Path(state_path) if state_path else None
        self.sessions: dict[str, Session] = {}
        self.max_sessions = max_sessions
        self.session_ttl = session_ttl
        self._ids = itertools.count(1)
        # Requests are served from several threads (ImagineServer) while manuals arrive on another.
        self.lock = threading.RLock()
        self._restore()

    @property
    def model_name(self) -> str:
        return f"{self.kind} ({self.config.get('preset', '?')}, {self.config.get('steps', '?')} steps)"

    def state(self, agent: str | None = None) -> ManualState:
        """An agent's manual state (None: the first agent's). Raises RequestError for an agent the
        server does not serve."""
        name = self.default_agent if agent is None else agent
        try:
            return self.agents[name]
        except KeyError:
            served = ", ".join(repr(a) for a in self.agents)
            raise RequestError(f"this server serves no agent {name!r} (it serves {served})") from None

    # The first agent's manual, as the single-agent system and its tests read it.
    manual = property(lambda self: self.state().manual)
    reading = property(lambda self: self.state().reading)
    manual_version = property(lambda self: self.state().version)
    manual_source = property(lambda self: self.state().source)
    game = property(lambda self: self.state().game)
    _batch = property(lambda self: self.state().batch)

    # ------------------------------------------------------------------ manual
    def older(self, signed_at: float | None, agent: str | None = None) -> int | None:
        """The version of an agent's manual in force when a manual signed at `signed_at` was signed
        before it (an old manual delivered again), else None."""
        with self.lock:
            state = self.state(agent)
            return state.version if signed_at is not None and signed_at < state.signed_at else None

    def set_manual(
        self,
        descriptions: list[str],
        source: str = "",
        agent: str | None = None,
        facts: Sequence[dict] = (),
        signed_at: float = 0.0,
    ) -> tuple[int, bool]:
        """Replace an agent's manual, with the facts a person stated of its board's entities
        (answers to the reading's questions). Returns (version, changed): the same text and facts
        again is not a new version (a latched manual is delivered again to a restarted node). A
        rejected manual changes nothing."""
        with self.lock:
            state = self.state(agent)
            board = self.board(agent)
            stated = [check_fact(f, board) for f in facts]
            if state.manual == list(descriptions) and state.facts == stated and state.batch is not None:
                return state.version, False
            if state.manual == list(descriptions) and state.batch is not None:
                batch = state.batch  # only the facts changed: the words are read already
            else:
                batch = self.model.read_manual(descriptions, self.encoder)
            batch = replace(batch, facts=tuple(stated))
            self._assign(state, list(descriptions), batch, *self._read_back(descriptions, batch))
            # The newest signature taken stays the floor, through the environment's unsigned manuals too.
            state.source, state.signed_at = source, max(state.signed_at, float(signed_at))
            self._save()
            return state.version, True

    def set_fleet_manual(
        self, descriptions: list[str], source: str = "", signed_at: float = 0.0
    ) -> dict[str, tuple[int, bool]]:
        """Give every agent the same manual (read once): each agent's (version, changed)."""
        with self.lock:
            batch = self.model.read_manual(descriptions, self.encoder)  # raises before anything changes
            reading = self._read_back(descriptions, batch)
            out = {}
            for name, state in self.agents.items():
                if state.manual == list(descriptions) and not state.facts and state.batch is not None:
                    out[name] = (state.version, False)
                    continue
                self._assign(state, list(descriptions), batch, *reading)
                state.source, state.signed_at = source, max(state.signed_at, float(signed_at))
                out[name] = (state.version, True)
            self._save()
            return out

    def _read_back(self, descriptions: list[str], batch: ManualBatch) -> tuple[list, list | None]:
        """Which entity the model reads each description as about, and what it is unsure of."""
        return read_identities(self.model, self.encoder, descriptions), unsure_fields(self.model, batch, descriptions)

    @staticmethod
    def _assign(state: ManualState, manual: list[str], batch: ManualBatch, reading, unsure) -> None:
        state.manual, state.batch, state.cond = manual, batch, None
        state.reading, state.unsure = reading, unsure
        state.version += 1

    def board(self, agent: str | None = None) -> list[str] | None:
        """The identities on the board of an agent's game; None when the game is not known yet."""
        from ..data.splits import load_split

        split, _, index = self.state(agent).game.rpartition(":")
        try:
            game = load_split(split)[int(index)]
        except (LwmError, ValueError, IndexError, KeyError, OSError):
            return None
        return [e.identity for e in game.entities]

    def ungrounded(self, agent: str | None = None) -> str | None:
        """What to tell a person about an agent's new manual: a description the world model reads as
        about an entity that is not on its board, and what a hedged model is unsure of because the
        words leave it open (world/reading.py); None when there is nothing to say."""
        with self.lock:
            state, board = self.state(agent), self.board(agent)
            if not state.manual:
                return None
            grounded, unsure = self._on_board(state, board)
            notes = [unsure_note(state.manual, unsure)]
            if board is not None and state.reading is not None:
                notes.insert(0, ungrounded_note(state.manual, state.reading, board, grounded))
            return "; ".join(n for n in notes if n) or None

    def _on_board(self, state: ManualState, board: list[str] | None) -> tuple[list | None, list | None]:
        """A model that grounds its words on the board (hedged_reading.ground_words) reads them as
        grounded: per description the board entities it is taken as about there ([one], [several]:
        one of them, each description a different one; []: open), and what the grounded words
        leave open. (None, the read-back) for any other model or board."""
        if board is None or state.batch is None or state.batch.routed is None:
            return None, state.unsure
        ids = torch.tensor([[IDENTITIES[b] for b in board]])
        read = self.model.on_board(state.batch, ids)
        if read is state.batch:
            return None, state.unsure
        grounded = []
        for entity, among in zip(code_fields(read.routed[0])[0].tolist(), read.among[0], strict=True):
            narrowed = [] if among.all() else [ID_TO_IDENTITY[int(i)] for i in torch.nonzero(among).flatten()]
            grounded.append([ID_TO_IDENTITY[entity]] if entity else narrowed)
        return grounded, unsure_fields(self.model, read, state.manual)

    def take_env_manual(
        self, descriptions: list[str], episode_id: str = "", agent: str | None = None
    ) -> tuple[int, bool]:
        """The environment's manual is the default: it replaces the agent's manual when no person
        has given one, or when the game changed (a person's manual was about the previous game)."""
        game = game_of(episode_id) if episode_id else ""
        with self.lock:
            state = self.state(agent)
            if state.source not in ("", "env") and (not game or game == state.game):
                return state.version, False
            state.game = game or state.game
            return self.set_manual(descriptions, "env", agent)

    def status(self, agent: str | None = None) -> dict:
        with self.lock:
            return self._status(self.default_agent if agent is None else agent)

    def _status(self, agent: str) -> dict:
        state = self.state(agent)
        out = {
            "node": "lwm_world_model",
            "ready": True,
            "model": self.model_name,
            "checkpoint": str(self.checkpoint),
            "manual_version": state.version,
            "manual_source": state.source,
            "sessions": len(self.sessions),
            "game": state.game,
        }
        if agent:
            out["agent"] = agent
        if state.manual:
            out["manual"] = state.manual
        if state.facts:
            out["facts"] = state.facts
        board = self.board(agent)
        if board is not None:
            out["board"] = board
            if state.manual and state.reading is not None and any(r is not None for r in state.reading):
                grounded, unsure = self._on_board(state, board)
                out["reading"] = grounding(state.reading, board, unsure, grounded)
            read = self._reading(state, board)
            if read is not None:
                out["belief"] = read.to_json()
                out["questions"] = [q.to_json() for q in read.questions()]
        return out

    def _reading(self, state: ManualState, board: Sequence[str]):
        """The manual's reading on a board (world/manual_reading.py), or None: no manual yet, or a
        model with no reading calibration."""
        if state.batch is None:
            return None
        ids = torch.tensor([[IDENTITIES[b] for b in board]])
        return self.model.on_board(state.batch, ids).reading

    def _read(self, request: dict) -> dict:
        """Op `read`: the manual's reading on the board of the request's start observation."""
        batch, manual, version, _ = self._manual_for(request)
        start = self._starts(request)[:1]
        read = self.model.on_board(batch, board_of(start)).reading
        out = {"ok": True, "op": "read", "model": self.model_name, "manual_version": version, "manual": manual}
        return out if read is None else {**out, **read.answer()}

    def _save(self) -> None:
        if self.state_path is None:
            return
        self.state_path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.state_path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"agents": {name: s.to_json() for name, s in self.agents.items()}}))
        os.replace(tmp, self.state_path)

    def _restore(self) -> None:
        """Each served agent's manual from the state file; a file from before fleets (one manual,
        no `agents`) is the first agent's. Agents the file does not know start with no manual."""
        if self.state_path is None or not self.state_path.is_file():
            return
        try:
            saved = json.loads(self.state_path.read_text())
            by_agent = saved["agents"] if "agents" in saved else {self.default_agent: saved}
            for name, entry in by_agent.items():
                if name not in self.agents:
                    continue
                state = self.agents[name]
                if entry.get("manual"):
                    facts = tuple(check_fact(f) for f in entry.get("facts", []))
                    state.batch = replace(self.model.read_manual(entry["manual"], self.encoder), facts=facts)
                    state.manual = list(entry["manual"])
                    state.reading, state.unsure = self._read_back(state.manual, state.batch)
                state.version = int(entry.get("version", 0))
                state.source = str(entry.get("source", ""))
                state.signed_at = float(entry.get("signed_at", 0.0))
                state.game = str(entry.get("game", ""))
        except (OSError, ValueError, TypeError, KeyError, AttributeError) as exc:
            raise LwmError(f"cannot read the world-model server state {self.state_path}: {exc}") from None

    # ------------------------------------------------------------------ requests
    def handle(self, request: dict) -> dict:
        """The response to an imagine request that messages.validate accepted (schema and real start
        states); raises LwmError for one it cannot serve."""
        op = request.get("op", "imagine")
        began = time.perf_counter()
        with self.lock:
            serve = {"open": self._open, "step": self._step, "close": self._close, "read": self._read}
            out = serve.get(op, self.imagine)(request)
        out["seconds"] = round(time.perf_counter() - began, 4)
        return out

    def _manual_for(self, request: dict) -> tuple[ManualBatch, list[str], int, ManualState | None]:
        """The manual a request is imagined under: its own, or its agent's current one (then also
        that agent's state, whose conditioning is cached)."""
        if "manual" in request:
            return self.model.read_manual(request["manual"], self.encoder), list(request["manual"]), 0, None
        state = self.state(request.get("agent"))
        if state.batch is None:
            raise RequestError("no manual yet: publish one on feedback/manual or put one in the request")
        return state.batch, list(state.manual), state.version, state

    @staticmethod
    def trajectory_count(request: dict) -> int:
        """How many trajectories an `imagine` or `open` request imagines: one per action sequence
        of a one-shot request that gives them, else `n`, else one per start observation."""
        if request.get("op", "imagine") == "imagine" and "actions" in request:
            return len(request["actions"])
        return int(request.get("n", len(request["observations"]) if "observations" in request else 1))

    def _starts(self, request: dict) -> np.ndarray:
        """[n, 4, 3]: the start observation of each trajectory (game states: messages.validate
        checked them); a request gives one for all or one each."""
        given = request["observations"] if "observations" in request else [request["observation"]]
        starts = np.asarray(given, np.uint8)
        n = self.trajectory_count(request)
        if len(starts) not in (1, n):
            raise RequestError(f"give one start observation or one per trajectory ({n}), got {len(starts)}")
        return np.broadcast_to(starts, (n, *starts.shape[1:]))

    def imagine(self, request: dict) -> dict:
        """One-shot imagination (op `imagine`), in a batch of its own."""
        shot = self.one_shot(request)
        run_alone(self.model, shot)
        return self.answer(shot)

    @staticmethod
    def is_one_shot(request: dict) -> bool:
        """Whether a request can join a continuous batch (an `imagine`, not a session op)."""
        return request.get("op", "imagine") == "imagine"

    def one_shot(self, request: dict) -> OneShot:
        """A one-shot request as a `OneShot` of a continuous batch (raises RequestError for a request
        that cannot be served). It reads the manual current now, whenever its steps run."""
        with self.lock:
            batch, manual, version, state = self._manual_for(request)
        max_steps = int(request.get("max_steps", 32))
        starts, actions = self._trajectories(request, max_steps)
        return OneShot(
            condition_rows(self._conditioning(batch, state, board_of(starts[:1])), len(starts)),
            starts,
            actions,
            max_steps,
            float(request.get("temperature", 1.0)),
            int(request.get("seed", 0)),
            bool(request.get("constrained", False)),
            info={"manual": manual, "manual_version": version},
        )

    def _conditioning(self, batch: ManualBatch, state: ManualState | None, board: torch.Tensor) -> Conditioning:
        """The model's conditioning on a manual read on a board (`board` [1, 3] identity ids); an
        agent's current manual's is computed once for the words it reads, not per request (a few
        milliseconds of the text encoder each, measured): once per manual, unless the model grounds
        its words on the board and the board changes what they say."""
        read = self.model.on_board(batch, board)
        if state is None or state.batch is not batch:
            return self.model.condition_on(read)
        words = () if read is batch else tuple(read.routed.flatten().tolist())
        if read.among is not None:  # the entities the board leaves each description are words too
            words += tuple(read.among.flatten().tolist())
        if read.reading is not None:  # a reading is of one board, with the facts stated
            words += (*board.flatten().tolist(), repr(read.facts))
        if state.cond is None or state.cond_words != words:
            state.cond, state.cond_words = self.model.condition_on(read), words
        return state.cond

    def answer(self, shot: OneShot) -> dict:
        """The response to a one-shot request that has ended."""
        return self.response(shot.result(), shot.info)

    def response(self, imagination: Imagination, info: dict) -> dict:
        """The response to a one-shot request: what was imagined, under the manual in `info`."""
        return {
            "ok": True,
            "model": self.model_name,
            "manual_version": info["manual_version"],
            "manual": info["manual"],
            "trajectories": imagination.to_json(),
        }

    def _trajectories(self, request: dict, max_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """A one-shot request's start observation and actions per trajectory ([n, 4, 3], [n, max_steps])."""
        starts = self._starts(request)
        n = len(starts)
        if "actions" in request:
            actions = np.full((n, max_steps), 4, dtype=np.int64)
            for i, seq in enumerate(request["actions"]):
                actions[i, : min(len(seq), max_steps)] = seq[:max_steps]
        else:
            actions = np.random.default_rng(int(request.get("seed", 0))).integers(5, size=(n, max_steps))
        return starts, actions

    def _open(self, request: dict) -> dict:
        self._expire()
        if len(self.sessions) >= self.max_sessions:
            raise RequestError(f"{self.max_sessions} imagination sessions are open; close one first")
        batch, manual, version, _ = self._manual_for(request)
        starts = self._starts(request)
        rollout = StepwiseImagination(
            self.model,
            batch,
            starts,
            len(starts),
            int(request.get("max_steps", 32)),
            float(request.get("temperature", 1.0)),
            int(request.get("seed", 0)),
            constrained=bool(request.get("constrained", False)),
        )
        sid = f"s{next(self._ids)}"
        self.sessions[sid] = Session(rollout, version)
        return {
            "ok": True,
            "op": "open",
            "session": sid,
            "model": self.model_name,
            "manual_version": version,
            "manual": manual,
            "active": rollout.active.tolist(),
        }

    def _session(self, request: dict) -> tuple[str, Session]:
        sid = request["session"]
        session = self.sessions.get(sid)
        if session is None:
            raise RequestError(f"no imagination session {sid!r} (never opened, closed, or expired)")
        session.last_used = time.monotonic()
        return sid, session

    def _step(self, request: dict) -> dict:
        sid, session = self._session(request)
        r = session.rollout
        if r.finished:
            raise RequestError(f"session {sid} has ended; close it")
        stepped = r.step(np.asarray(request["actions"]))
        t = r.t
        conf = r.result().confidence()
        return {
            "ok": True,
            "op": "step",
            "session": sid,
            "manual_version": session.manual_version,
            "t": t,
            "stepped": stepped.tolist(),
            "observations": r.observations[stepped, t].tolist(),
            "rewards": r.rewards[stepped, t].tolist(),
            "dones": r.dones[stepped, t].tolist(),
            "confidence": conf[stepped, t].round(4).tolist(),
            "active": r.active.tolist(),
            "finished": r.finished,
        }

    def _close(self, request: dict) -> dict:
        sid = request["session"]
        self.sessions.pop(sid, None)  # closing twice is harmless (a retried close)
        return {"ok": True, "op": "close", "session": sid}

    def _expire(self) -> None:
        now = time.monotonic()
        for sid in [s for s, v in self.sessions.items() if now - v.last_used > self.session_ttl]:
            del self.sessions[sid]


def error_response(error: Exception) -> dict:
    return {"ok": False, "error": str(error)}


def serve_json(
    sim: WorldModelServer, text: str, handle: Callable[[dict], dict] | None = None, agent: str | None = None
) -> tuple[str, Exception | None]:
    """What the service answers to a request string (a valid response, never an exception), and
    the error when the request was refused, for the caller to report. `handle` (default
    `sim.handle`) answers a valid request: the ImagineServer passes its batching one. `agent`: the
    agent whose manual a request that names none is imagined under (an agent's own service)."""
    try:
        request = messages.parse("imagine_request", text)
        if agent is not None:
            request.setdefault("agent", agent)
        return messages.dump("imagine_response", (handle or sim.handle)(request)), None
    except Exception as exc:  # a bad request must never take the server down
        return messages.dump("imagine_response", error_response(exc)), exc


__all__ = ["ManualState", "RequestError", "WorldModelServer", "error_response", "serve_json"]

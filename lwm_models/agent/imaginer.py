"""Where the agent imagines: the world model's owner, reached through its request interface.

The planner holds no world model. Everything it imagines (plans, sampled futures, online-imitation
rounds, the execution monitor) goes through `ServiceImaginer`, which speaks the world-model server's
imagine requests (msgs_json/imagine_request) over any transport: a ROS service call in the planner
node, `WorldModelServer.handle` in process (tests, benchmarks). A policy acts inside imagination through a
step-wise session: open, one `step` per time step with the running trajectories' actions, close.

`LocalImaginer` runs a world model in process with the same interface (Table 3, which compares
world models, owns them).
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import LwmError
from ..world.base import ManualBatch, WorldModel
from ..world.imagine import Imagination, Policy, Trajectories, imagine


class ImagineError(LwmError, RuntimeError):
    """The world-model server refused a request (the message says why)."""


class Unavailable(LwmError, ConnectionError):
    """The transport could not reach the world-model server (not started, restarting, timed out)."""


@dataclass
class CallStats:
    calls: int = 0
    round_trip_s: float = 0.0  # what the caller waited
    server_s: float = 0.0  # what the world-model server spent (its `seconds`)
    retries: int = 0


@dataclass
class ServiceImaginer:
    """call(request dict) -> response dict; raises Unavailable when the world-model server cannot be reached.

    A rollout whose session is lost (the world-model server restarted) or whose transport fails is started
    again from scratch, for up to `retry_for` seconds: imagination is stateless for the caller.
    """

    call: Callable[[dict], dict]
    retry_for: float = 120.0
    constrained: bool = False  # imagine under the game's rules (world/constraints.py)
    stats: CallStats = field(default_factory=CallStats)

    def request(self, payload: dict) -> dict:
        began = time.perf_counter()
        answer = self.call({"version": 1, **payload})
        self.stats.calls += 1
        self.stats.round_trip_s += time.perf_counter() - began
        self.stats.server_s += float(answer.get("seconds", 0.0))
        if not answer.get("ok"):
            raise ImagineError(answer.get("error", "the world-model server refused the request"))
        return answer

    def _retrying(self, attempt: Callable[[], Imagination]) -> Imagination:
        deadline = time.monotonic() + self.retry_for
        while True:
            try:
                return attempt()
            except (Unavailable, ImagineError) as exc:
                lost = isinstance(exc, Unavailable) or "no imagination session" in str(exc)
                if not lost or time.monotonic() > deadline:
                    raise
                self.stats.retries += 1
                time.sleep(0.5)

    def rollout(
        self,
        starts: np.ndarray,
        policy: Policy,
        n: int | None = None,
        max_steps: int = 32,
        seed: int = 0,
        temperature: float = 1.0,
        constrained: bool | None = None,
    ) -> Imagination:
        """n trajectories from starts ([4, 3], or [n, 4, 3]), each step's actions chosen by
        policy(observations [k, t, 4, 3], trajectory indices [k], t); under the game's rules if
        `constrained` (None: this imaginer's default)."""
        starts = np.asarray(starts, dtype=np.uint8)
        n = n or (1 if starts.ndim == 2 else len(starts))
        ruled = self.constrained if constrained is None else constrained
        return self._retrying(lambda: self._rollout_once(starts, policy, n, max_steps, seed, temperature, ruled))

    def _rollout_once(self, starts, policy, n, max_steps, seed, temperature, constrained) -> Imagination:
        req = {"op": "open", "n": n, "max_steps": max_steps, "seed": int(seed), "temperature": temperature}
        if constrained:
            req["constrained"] = True
        req.update({"observation": starts.tolist()} if starts.ndim == 2 else {"observations": starts.tolist()})
        opened = self.request(req)
        sid = opened["session"]
        out = Trajectories(np.broadcast_to(starts, (n, 4, 3)), max_steps)
        active = np.asarray(opened["active"], dtype=np.int64)
        try:
            t = 0
            while len(active):
                t += 1
                actions = np.asarray(policy(out.observations[active, :t], active, t), dtype=np.int64)
                step = self.request({"op": "step", "session": sid, "actions": actions.tolist()})
                stepped = np.asarray(step["stepped"], dtype=np.int64)
                observations = np.asarray(step["observations"], dtype=np.uint8).reshape(-1, 4, 3)
                rewards, dones, confidence = step["rewards"], step["dones"], step["confidence"]
                out.put(stepped, int(step["t"]), actions, observations, rewards, dones, confidence)
                active = np.asarray(step["active"], dtype=np.int64)
                if step["finished"]:
                    break
        finally:
            try:
                self.request({"op": "close", "session": sid})
            except (Unavailable, ImagineError):
                pass  # the session expires on its own
        return out.result(opened.get("manual_version", 0))

    def read(self, start: np.ndarray) -> dict | None:
        """The manual's reading on the board of `start` [4, 3] (the service's op `read`): None
        where the world model reads no such thing (only models with a reading calibration do)."""
        answer = self.request({"op": "read", "observation": np.asarray(start, dtype=np.uint8).tolist()})
        return answer if "reading" in answer else None

    def replay(self, starts: np.ndarray, actions: list[list[int]], max_steps: int = 32, seed: int = 0) -> Imagination:
        """One-shot: each trajectory replays its action sequence (padded with 'stay')."""
        starts = np.asarray(starts, dtype=np.uint8)

        def once() -> Imagination:
            req = {"actions": [list(map(int, a)) for a in actions], "max_steps": max_steps, "seed": int(seed)}
            if self.constrained:
                req["constrained"] = True
            req.update({"observation": starts.tolist()} if starts.ndim == 2 else {"observations": starts.tolist()})
            answer = self.request(req)
            out = Trajectories(np.broadcast_to(starts, (len(actions), 4, 3)), max_steps)
            for i, tr in enumerate(answer["trajectories"]):
                observations = np.asarray(tr["observations"], dtype=np.uint8)
                out.put_trajectory(i, observations, tr["actions"], tr["rewards"], tr["dones"], tr["confidence"])
            return out.result(answer.get("manual_version", 0))

        return self._retrying(once)


@dataclass
class LocalImaginer:
    """A world model and its manual in this process, with ServiceImaginer's rollout interface."""

    world: WorldModel
    manual: ManualBatch
    manual_version: int = 0
    constrained: bool = False

    def rollout(self, starts, policy, n=None, max_steps=32, seed=0, temperature=1.0, constrained=None) -> Imagination:
        starts = np.asarray(starts, dtype=np.uint8)
        n = n or (1 if starts.ndim == 2 else len(starts))
        return imagine(
            self.world,
            self.manual,
            starts,
            n=n,
            policy=policy,
            max_steps=max_steps,
            seed=seed,
            temperature=temperature,
            constrained=self.constrained if constrained is None else constrained,
        )

    def read(self, start: np.ndarray) -> dict | None:
        """The manual's reading on the board of `start` [4, 3], as ServiceImaginer.read answers it."""
        from ..world.imagine import board_of

        read = self.world.on_board(self.manual, board_of(np.asarray(start, dtype=np.uint8)[None])).reading
        return None if read is None else read.answer()


def in_process(server) -> Callable[[dict], dict]:
    """A transport to a WorldModelServer in this process that takes the same JSON path as the service
    (encode, validate, handle, encode, decode), for tests and benchmarks."""
    from ..world.model_server import serve_json

    return lambda request: json.loads(serve_json(server, json.dumps(request))[0])


__all__ = ["CallStats", "ImagineError", "LocalImaginer", "ServiceImaginer", "Unavailable", "in_process"]

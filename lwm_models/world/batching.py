"""Continuous batching of /lwm/imagine: concurrent one-shot requests share the model's steps.

A step of the world model costs about the same for one trajectory as for sixteen (it is bound by
per-operation overhead, not arithmetic), so a simulator serving clients one at a time wastes most
of its time. `ImagineServer.serve` is called from many threads at once (the node's service
callbacks); one worker thread runs a `ContinuousBatch`: before each step it admits every request
that has queued (first come, first served, up to the batch's row limit), and a request is answered
as soon as its last trajectory ends. No request waits for a batch to fill or to finish: a lone
request starts at once, and one that arrives under load joins at the next step.

Each request keeps its own seeded random stream inside the batch, so its answer is the one it
would get alone. Session ops (open/step/close) are not batched: they run in the caller's thread.
"""

from __future__ import annotations

import queue
import threading
import time
from collections import deque
from dataclasses import dataclass, field

from ..errors import LwmError
from .continuous import MAX_ROWS, ContinuousBatch, Track
from .simulator import Simulator, serve_json


class ShuttingDown(LwmError):
    """A request that arrived or waited while the server stopped."""


@dataclass
class _Job:
    request: dict
    size: int  # trajectories
    done: threading.Event = field(default_factory=threading.Event)
    response: dict | None = None
    error: Exception | None = None

    def finish(self, response: dict | None = None, error: Exception | None = None) -> None:
        self.response, self.error = response, error
        self.done.set()


class ImagineServer:
    """Thread-safe request-string -> response-string service over a Simulator."""

    def __init__(self, sim: Simulator, max_trajectories: int = MAX_ROWS) -> None:
        self.sim = sim
        self.batch = ContinuousBatch(sim.model, max_trajectories)
        self.requests = 0  # one-shot requests answered: for status and benchmarks
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._closed = threading.Event()
        self._worker = threading.Thread(target=self._work, name="imagine-batcher", daemon=True)
        self._worker.start()

    def serve(self, text: str) -> tuple[str, Exception | None]:
        """What the service answers to a request string (a valid response, never an exception),
        and the error when the request was refused, for the caller to report."""
        return serve_json(self.sim, text, self.handle)

    def handle(self, request: dict) -> dict:
        """The response to a valid request: one-shot requests wait for their batch."""
        if not self.sim.is_one_shot(request):
            return self.sim.handle(request)
        if self._closed.is_set():
            raise ShuttingDown("the simulator is shutting down")
        began = time.perf_counter()
        job = _Job(request, self.sim.trajectory_count(request))
        self._queue.put(job)
        while not job.done.wait(0.5):
            if not self._worker.is_alive():  # it stopped after this job was queued
                raise ShuttingDown("the simulator is shutting down")
        if job.error is not None:
            raise job.error
        return {**job.response, "seconds": round(time.perf_counter() - began, 4)}

    def close(self, timeout: float = 1.0) -> None:
        """Stop: the requests being imagined may finish for `timeout` seconds (a time limit of 32
        steps takes about 0.8 s under load); queued ones are answered with an error at once, so
        that a server's waiting calls end and it can exit within its stop deadline (a ROS node
        has 1.5 s for all of its teardown)."""
        self._closed.set()
        self._queue.put(None)
        self._worker.join(timeout)

    # ------------------------------------------------------------------ the worker
    def _work(self) -> None:
        waiting: deque[_Job] = deque()
        closing = False
        while True:
            closing = self._take(waiting, wait=not self.batch and not waiting) or closing
            if closing:
                while waiting:
                    waiting.popleft().finish(error=ShuttingDown("the simulator is shutting down"))
                if not self.batch:
                    return
            while waiting and self.batch.fits(waiting[0].size):
                self._admit(waiting.popleft())
            if self.batch:
                self._step()

    def _take(self, waiting: deque[_Job], wait: bool) -> bool:
        """Move what has queued to `waiting` (blocking for the first when `wait`); True when the
        server is closing."""
        while True:
            try:
                job = self._queue.get(block=wait)
            except queue.Empty:
                return False
            if job is None:
                return True
            waiting.append(job)
            wait = False

    def _admit(self, job: _Job) -> None:
        try:
            track = self.sim.one_shot(job.request)
        except Exception as exc:  # this request alone is refused
            job.finish(error=exc)
            return
        track.info["job"] = job
        self.batch.admit(track)

    def _step(self) -> None:
        try:
            ended = self.batch.step()
        except Exception as exc:  # not expected: fail what was running, keep serving
            for track in self.batch.tracks:
                track.info["job"].finish(error=exc)
            self.batch = ContinuousBatch(self.sim.model, self.batch.max_rows)
            return
        for track in ended:
            self._answer(track)

    def _answer(self, track: Track) -> None:
        self.requests += 1
        track.info["job"].finish({**self.sim.answer(track), "batched": track.peak})


__all__ = ["ImagineServer", "ShuttingDown"]

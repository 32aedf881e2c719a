"""Dynamic batching of /lwm/imagine: concurrent one-shot requests imagined as one batch.

A world model imagines 64 trajectories in about three times the time of one (the step is bound
by per-operation overhead, not arithmetic), so the simulator serving clients one at a time wastes
most of its time. `ImagineServer.serve` is called from many threads at once (the node's service
callbacks); one worker thread takes every request that has queued while the previous batch ran,
groups those that can share a batch (same manual, time limit and temperature: `Simulator.batch_key`)
and imagines each group at once, as inference servers do. No request waits for a batch to fill:
a lone request is imagined at once, and under load a batch forms from what queued meanwhile.

Each request keeps its own seeded random stream inside the batch, so its answer is the one it
would get alone. Session ops (open/step/close) are not batched: they run in the caller's thread.
"""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field

from ..errors import LwmError
from .simulator import Simulator, serve_json

MAX_BATCH_TRAJECTORIES = 256  # per batch: bounds the memory and latency of one batch


class ShuttingDown(LwmError):
    """A request that arrived or waited while the server stopped."""


@dataclass
class _Job:
    request: dict
    key: tuple
    done: threading.Event = field(default_factory=threading.Event)
    response: dict | None = None
    error: Exception | None = None


class ImagineServer:
    """Thread-safe request-string -> response-string service over a Simulator."""

    def __init__(self, sim: Simulator, max_trajectories: int = MAX_BATCH_TRAJECTORIES) -> None:
        self.sim = sim
        self.max_trajectories = max_trajectories
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self.batches = 0  # batches imagined, and the requests in them: for status and benchmarks
        self.batched_requests = 0
        self._closed = threading.Event()
        self._worker = threading.Thread(target=self._work, name="imagine-batcher", daemon=True)
        self._worker.start()

    def serve(self, text: str) -> tuple[str, Exception | None]:
        """What the service answers to a request string (a valid response, never an exception),
        and the error when the request was refused, for the caller to report."""
        return serve_json(self.sim, text, self.handle)

    def handle(self, request: dict) -> dict:
        """The response to a valid request: one-shot requests wait for their batch."""
        key = self.sim.batch_key(request)
        if key is None:
            return self.sim.handle(request)
        if self._closed.is_set():
            raise ShuttingDown("the simulator is shutting down")
        began = time.perf_counter()
        job = _Job(request, key)
        self._queue.put(job)
        job.done.wait()
        if job.error is not None:
            raise job.error
        return {**job.response, "seconds": round(time.perf_counter() - began, 4)}

    def close(self, timeout: float = 1.5) -> None:
        """Stop: the batch being imagined finishes; queued requests are answered with an error at
        once, so that the node's waiting service calls end and it can exit."""
        self._closed.set()
        self._queue.put(None)
        self._worker.join(timeout)

    # ------------------------------------------------------------------ the worker
    def _work(self) -> None:
        while True:
            job = self._queue.get()
            if job is None:
                return
            jobs = [job]
            while True:  # everything that queued while the last batch ran
                try:
                    more = self._queue.get_nowait()
                except queue.Empty:
                    break
                if more is None:
                    self._queue.put(None)  # finish this round, then stop
                    break
                jobs.append(more)
            for batch in self._batches(jobs):
                if self._closed.is_set():
                    for job in batch:
                        job.error = ShuttingDown("the simulator is shutting down")
                        job.done.set()
                else:
                    self._run(batch)

    def _batches(self, jobs: list[_Job]) -> list[list[_Job]]:
        """Jobs grouped by batch key (arrival order kept), each group cut at max_trajectories."""
        groups: dict[tuple, list[list[_Job]]] = {}
        filled: dict[tuple, int] = {}  # trajectories in each key's last chunk
        for job in jobs:
            n = self.sim.trajectory_count(job.request)
            chunks = groups.setdefault(job.key, [[]])
            if chunks[-1] and filled[job.key] + n > self.max_trajectories:
                chunks.append([])
                filled[job.key] = 0
            chunks[-1].append(job)
            filled[job.key] = filled.get(job.key, 0) + n
        return [chunk for chunks in groups.values() for chunk in chunks]

    def _run(self, batch: list[_Job]) -> None:
        try:
            responses = self.sim.imagine_together([job.request for job in batch])
        except Exception as exc:
            if len(batch) > 1:  # one bad request must not fail the others: serve them alone
                for job in batch:
                    self._run([job])
                return
            batch[0].error = exc
            batch[0].done.set()
            return
        self.batches += 1
        self.batched_requests += len(batch)
        for job, response in zip(batch, responses):
            job.response = {**response, "batched": len(batch)}
            job.done.set()


__all__ = ["ImagineServer", "MAX_BATCH_TRAJECTORIES", "ShuttingDown"]

"""Continuous batching of /lwm/imagine: concurrent one-shot requests share the model's steps.

A step of the world model costs about the same for one trajectory as for sixteen (it is bound by
per-operation overhead, not arithmetic), so a world-model server serving clients one at a time wastes most
of its time. `ImagineServer.serve` is called from many threads at once (the node's service
callbacks); one worker thread runs a `ContinuousBatch`: before each step it admits every request
that has queued (first come, first served, up to the batch's row limit), and a request is answered
as soon as its last trajectory ends. No request waits for a batch to fill or to finish: a lone
request starts at once, and one that arrives under load joins at the next step.

Each request keeps its own seeded random stream inside the batch, so its answer is the one it
would get alone. Session ops (open/step/close) are not batched: they run in the caller's thread.

`WorkerImagineServer` runs the same batch in a process of its own (world/imagine_worker.py), so that
the model's steps do not share a GIL with the threads that receive and answer the calls: what the
world-model server node uses.
"""

from __future__ import annotations

import itertools
import queue
import subprocess
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from multiprocessing.connection import Connection

import numpy as np

from ..errors import LwmError
from .continuous import MAX_ROWS, ContinuousBatch, OneShot
from .imagine import Imagination
from .imagine_worker import STOP, await_ready, launch_worker, shot_message
from .model_server import WorldModelServer, serve_json

RECENT = 1000  # calls the server's load figures (latency, batch) are taken over


class ShuttingDown(LwmError):
    """A request that arrived or waited while the server stopped."""


class WorkerLost(LwmError):
    """The worker process ended while a request was being imagined (it is started again)."""


@dataclass
class _Job:
    request: dict
    size: int  # trajectories
    shot: OneShot | None = None  # built by the server (WorkerImagineServer)
    done: threading.Event = field(default_factory=threading.Event)
    response: dict | None = None
    error: Exception | None = None

    def finish(self, response: dict | None = None, error: Exception | None = None) -> None:
        self.response, self.error = response, error
        self.done.set()


class ImagineServer:
    """Thread-safe request-string -> response-string service over a WorldModelServer."""

    def __init__(self, sim: WorldModelServer, max_trajectories: int = MAX_ROWS) -> None:
        self.sim = sim
        self.batch = ContinuousBatch(sim.model, max_trajectories)
        self.requests = 0  # one-shot requests answered: for status and benchmarks
        self.calls = 0  # answered, of every kind (session calls too)
        self.recent: deque[tuple[float, int]] = deque(maxlen=RECENT)  # (seconds, batch peak; 0: a session call)
        self.submitted = 0  # one-shot requests handed to the batch (tests wait on it, not on time)
        self._queue: queue.SimpleQueue[_Job | None] = queue.SimpleQueue()
        self._closed = threading.Event()
        self._worker = threading.Thread(target=self._work, name="imagine-batcher", daemon=True)
        self._worker.start()

    def serve(self, text: str, agent: str | None = None) -> tuple[str, Exception | None]:
        """What the service answers to a request string (a valid response, never an exception),
        and the error when the request was refused, for the caller to report. `agent`: whose
        manual a request that names none is imagined under."""
        return serve_json(self.sim, text, self.handle, agent)

    def handle(self, request: dict) -> dict:
        """The response to a valid request: one-shot requests wait for their batch."""
        if not self.sim.is_one_shot(request):  # a session's open, step or close
            answer = self.sim.handle(request)
            self._record(answer["seconds"], 0)
            return answer
        if self._closed.is_set():
            raise ShuttingDown("the world-model server is shutting down")
        began = time.perf_counter()
        job, answerer = self._submit(request)
        while not job.done.wait(0.5):
            if not answerer.is_alive():  # it stopped after this job was submitted
                raise ShuttingDown("the world-model server is shutting down")
        if job.error is not None:
            raise job.error
        answer = {**self._response(job), "seconds": round(time.perf_counter() - began, 4)}
        self._record(answer["seconds"], int(answer.get("batched", 1)))
        return answer

    def load(self) -> dict[str, float | int]:
        """Calls answered (all, and one-shot), and over the last RECENT calls: latency's median and
        99th percentile in ms, and the mean batch (trajectories stepped together) one-shot calls
        peaked at. Session calls (open, step, close) are served one at a time."""
        recent = list(self.recent)
        out: dict[str, float | int] = {"calls": self.calls, "one-shot calls": self.requests}
        if recent:
            ms = np.array([r[0] for r in recent]) * 1000
            out["latency p50 ms"] = round(float(np.percentile(ms, 50)), 1)
            out["latency p99 ms"] = round(float(np.percentile(ms, 99)), 1)
        batches = [r[1] for r in recent if r[1] > 0]
        if batches:
            out["mean batch"] = round(float(np.mean(batches)), 1)
        return out

    def _record(self, seconds: float, batch: int) -> None:
        self.calls += 1
        self.recent.append((seconds, batch))

    def _submit(self, request: dict) -> tuple[_Job, threading.Thread]:
        """Queue a one-shot request; returns its job and the thread that will finish it."""
        job = _Job(request, self.sim.trajectory_count(request))
        self._queue.put(job)
        self.submitted += 1
        return job, self._worker

    def _response(self, job: _Job) -> dict:
        return job.response

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
                    waiting.popleft().finish(error=ShuttingDown("the world-model server is shutting down"))
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
            shot = self.sim.one_shot(job.request)
        except Exception as exc:  # this request alone is refused
            job.finish(error=exc)
            return
        shot.info["job"] = job
        self.batch.admit(shot)

    def _step(self) -> None:
        try:
            ended = self.batch.step()
        except Exception as exc:  # not expected: fail what was running, keep serving
            for shot in self.batch.shots:
                shot.info["job"].finish(error=exc)
            self.batch = ContinuousBatch(self.sim.model, self.batch.max_rows)
            return
        for shot in ended:
            self._answer(shot)

    def _answer(self, shot: OneShot) -> None:
        self.requests += 1
        shot.info["job"].finish({**self.sim.answer(shot), "batched": shot.peak})


class _Worker:
    """One worker process, its pipe, the calls it is imagining and the thread that receives its
    answers; it starts a new process when its process dies (the calls it had get an error)."""

    def __init__(self, name: str, launch: Callable[[], tuple[subprocess.Popen, Connection]], closed: threading.Event):
        self.name, self._launch, self._closed = name, launch, closed
        self.proc, self.conn = launch()
        self.jobs: dict[int, _Job] = {}
        self.load = 0  # trajectories of the calls it has
        self.restarts = 0
        self.lock = threading.Lock()  # jobs, load and the pipe's sending end
        self.receiver = threading.Thread(target=self._receive, name=f"{name}-receiver", daemon=True)

    def start(self) -> None:
        await_ready(self.proc, self.conn)
        self.receiver.start()

    def submit(self, key: int, job: _Job) -> None:
        with self.lock:
            # Checked under the lock that stop() takes: a call that comes after the STOP is refused
            # as the server's stop, not as a lost worker (which would invite a retry).
            if self._closed.is_set():
                raise ShuttingDown("the world-model server is shutting down")
            self.jobs[key] = job
            self.load += job.size
            try:
                self.conn.send(shot_message(key, job.shot))
            except (OSError, ValueError):  # the process is gone; the receiver starts another
                self._pop(key)
                if self._closed.is_set():
                    raise ShuttingDown("the world-model server is shutting down") from None
                raise WorkerLost("the imagination worker stopped; try again") from None

    def stop(self) -> None:
        with self.lock:
            try:
                self.conn.send(STOP)
            except (OSError, ValueError):
                pass

    def wait(self, timeout: float) -> None:
        try:
            self.proc.wait(max(timeout, 0.0))
        except subprocess.TimeoutExpired:
            self.proc.kill()
            try:
                self.proc.wait(1.0)
            except subprocess.TimeoutExpired:
                # SIGKILL cannot be refused, but on a loaded machine the kernel may take longer to
                # tear down a process holding torch; closing must not fail for it (Popen reaps it).
                pass

    def fail_all(self, error: Exception) -> None:
        with self.lock:
            jobs, self.jobs, self.load = list(self.jobs.values()), {}, 0
        for job in jobs:
            job.finish(error=error)

    def _pop(self, key: int) -> _Job | None:
        job = self.jobs.pop(key, None)
        if job is not None:
            self.load -= job.size
        return job

    def _receive(self) -> None:
        while True:
            try:
                key, payload, peak = self.conn.recv()
            except (EOFError, OSError):
                if self._closed.is_set():
                    return self.fail_all(ShuttingDown("the world-model server is shutting down"))
                self.fail_all(WorkerLost("the imagination worker stopped; try again"))
                if not self._restart():
                    return
                continue
            with self.lock:
                job = self._pop(key)
            if job is None:
                continue
            if isinstance(payload, Imagination):
                job.finish((payload, peak))
            elif "shutting down" in payload:
                job.finish(error=ShuttingDown(payload))
            else:
                job.finish(error=LwmError(payload))

    def _restart(self) -> bool:
        self.wait(0.5)
        try:
            proc, conn = self._launch()
            await_ready(proc, conn)
        except (RuntimeError, OSError):
            return False
        with self.lock:
            self.proc, self.conn = proc, conn
        self.restarts += 1
        return True


class WorkerImagineServer(ImagineServer):
    """The ImagineServer with its batches in worker processes. The server's threads parse each call
    and build its `OneShot` (conditioning on the manual current when it arrives) and send it to the
    worker with the fewest trajectories in hand; the worker admits it into its continuous batch,
    steps and sends back what was imagined; a receiver thread per worker hands each answer to its
    caller. A worker that dies is started again: the calls it was imagining get an error, later
    ones are served.

    workers: processes, each with its own batch and one core's worth of model steps. A step of
    the small model costs nearly as much for one row as for eight, so one worker gives 8 clients
    the most rows per step; a second one uses a second core (docs/benchmarks.md)."""

    def __init__(
        self, sim: WorldModelServer, max_trajectories: int = MAX_ROWS, threads: int = 1, workers: int = 1
    ) -> None:
        if workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        self.sim = sim
        self.requests = 0
        self.calls = 0
        self.recent: deque[tuple[float, int]] = deque(maxlen=RECENT)
        self._closed = threading.Event()
        self._ids = itertools.count()
        self._pick = threading.Lock()

        def launch() -> tuple[subprocess.Popen, Connection]:
            return launch_worker(sim.checkpoint, max_trajectories, threads)

        # Launched together, so that their start-up (loading torch and the model) overlaps.
        self.workers = [_Worker(f"imagine-worker-{i}", launch, self._closed) for i in range(workers)]
        for worker in self.workers:
            worker.start()

    @property
    def restarts(self) -> int:
        """Worker processes started again after one died."""
        return sum(w.restarts for w in self.workers)

    def _submit(self, request: dict) -> tuple[_Job, threading.Thread]:
        shot = self.sim.one_shot(request)  # a request that cannot be served fails here, alone
        job = _Job(request, shot.size, shot)
        with self._pick:
            worker = min(self.workers, key=lambda w: w.load)
            worker.submit(next(self._ids), job)
        return job, worker.receiver

    def _response(self, job: _Job) -> dict:
        imagination, peak = job.response
        self.requests += 1
        return {**self.sim.response(imagination, job.shot.info), "batched": peak}

    def close(self, timeout: float = 1.0) -> None:
        """Stop: each worker answers what it is imagining for up to `timeout` seconds in all and
        refuses what waits; then one that has not ended is killed."""
        self._closed.set()
        deadline = time.monotonic() + timeout
        for worker in self.workers:
            worker.stop()
        for worker in self.workers:
            worker.wait(deadline - time.monotonic())
        for worker in self.workers:
            worker.receiver.join(0.05)
            worker.fail_all(ShuttingDown("the world-model server is shutting down"))


__all__ = ["ImagineServer", "ShuttingDown", "WorkerImagineServer", "WorkerLost"]

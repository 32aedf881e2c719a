"""The continuous batch in a process of its own: the model's steps off the server's GIL.

In the world-model server node the batch worker shared one GIL with the ROS executor threads that receive,
parse and answer the calls. Under 8 clients that process used 97% of one core while the other
core was idle, and the ROS work cost about a quarter of the calls per second that the same batch
ran without ROS (measured; docs/benchmarks.md, "The world-model server under load"). Here the server process keeps the
manual, parses requests, builds each call's OneShot (its conditioning, start observations, actions)
and answers; the worker process only admits one-shot requests, steps the model and sends back what was
imagined. A call's answer is the same as in a thread: the same model, the same seeded random
stream per call.

The worker reads the checkpoint itself (nothing big crosses the pipe: a one-shot request's conditioning is
one manual's id table, the answer a few small arrays). It ends when the server tells it to, or when
the pipe closes because the server died.
"""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from collections import deque
from multiprocessing.connection import Connection
from pathlib import Path

import torch

from .base import Conditioning
from .continuous import ContinuousBatch, OneShot

STOP = None  # the server's last message: answer what runs, refuse what waits, then exit


def shot_message(job: int, shot: OneShot) -> tuple:
    """What crosses the pipe for one call: plain arrays, so that no tensor is shared between
    processes (torch would pass them through shared-memory files)."""
    cond = {k: None if v is None else v.numpy() for k, v in vars(shot.cond).items()}
    return (job, cond, shot.first, shot.actions, shot.max_steps, shot.temperature, shot.seed, shot.constrained)


def _shot(message: tuple) -> tuple[int, OneShot]:
    job, cond, first, actions, max_steps, temperature, seed, constrained = message
    cond = Conditioning(**{k: None if v is None else torch.from_numpy(v) for k, v in cond.items()})
    return job, OneShot(cond, first, actions, max_steps, temperature, seed, constrained)


def serve_batches(conn: Connection, checkpoint: str, max_rows: int, threads: int) -> None:
    """The worker process: one-shot requests in, (job, imagination or error, peak) out, until STOP or EOF."""
    from .checkpoint import load_checkpoint

    # Its life is the pipe's: a Ctrl-C in the terminal or a SIGTERM to the process group is the
    # server's to handle (it stops the worker in order); the pipe closes when the server dies.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    torch.set_num_threads(max(1, threads))
    model, _ = load_checkpoint(Path(checkpoint))
    batch = ContinuousBatch(model, max_rows)
    waiting: deque[tuple[int, OneShot]] = deque()
    stopping = False
    conn.send(("ready", None, 0))
    try:
        while True:
            if stopping and not batch:
                return
            # Block only when there is nothing to step; between steps take whatever has arrived.
            while conn.poll(None if not batch and not waiting and not stopping else 0):
                message = conn.recv()
                if message is STOP:
                    stopping = True
                    break
                try:
                    waiting.append(_shot(message))
                except Exception as exc:  # this call alone is refused
                    conn.send((message[0], f"{type(exc).__name__}: {exc}", 0))
            if stopping:
                while waiting:
                    conn.send((waiting.popleft()[0], "the world-model server is shutting down", 0))
            while waiting and batch.fits(waiting[0][1].size):
                job, shot = waiting.popleft()
                shot.info["job"] = job
                batch.admit(shot)
            if batch:
                for shot in batch.step():
                    conn.send((shot.info["job"], shot.result(), shot.peak))
    except (EOFError, OSError):  # the server is gone
        return


def launch_worker(checkpoint: str | Path, max_rows: int, threads: int) -> tuple[subprocess.Popen, Connection]:
    """Start a worker process; returns (process, the server's end of the pipe) at once, before it
    has loaded the model (`await_ready`). A fresh interpreter (`python -m`), not a fork: the server
    has threads, ROS's among them, and multiprocessing's spawn would import the server's main module."""
    ours, theirs = socket.socketpair()
    cmd = [sys.executable, "-m", __name__, str(theirs.fileno()), str(checkpoint), str(max_rows), str(threads)]
    proc = subprocess.Popen(cmd, pass_fds=(theirs.fileno(),))
    theirs.close()
    return proc, Connection(ours.detach())


def await_ready(proc: subprocess.Popen, conn: Connection, timeout: float = 120) -> None:
    """Wait for a launched worker to have loaded its model; RuntimeError (and the worker killed) if
    it does not."""
    try:
        ready = conn.poll(timeout) and conn.recv()[0] == "ready"
    except (EOFError, OSError):
        ready = False
    if not ready:
        proc.kill()
        raise RuntimeError(f"the imagination worker process did not start (exit code {proc.wait()})")


def main(argv: list[str]) -> None:
    fd, checkpoint, max_rows, threads = argv
    serve_batches(Connection(int(fd)), checkpoint, int(max_rows), int(threads))


__all__ = ["STOP", "await_ready", "launch_worker", "serve_batches", "shot_message"]


if __name__ == "__main__":
    main(sys.argv[1:])

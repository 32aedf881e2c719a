"""Lanes: a few threads that run imagination's scripted steps side by side, one intra-op thread each.

A speculative step over many rows (world/speculative.py) is a chain of small decoder calls, and
torch's intra-op threads split each op of a call: at 16-64 rows of a few tokens each, an op is too
small to split well, and a process that asked for one thread (the system's nodes do) leaves the
other core idle. Cutting the rows into groups and stepping each group on a lane, a thread of its
own with one intra-op thread, made a one-thread process 1.4-1.7x faster at 16-32 rows on this
2-core machine, and a two-thread one neither faster nor slower (benchmarks/imagination.py;
docs/speed.md has the figures). TorchScript releases the GIL while it
runs a graph, so Python threads suffice.

A lane runs its work under `torch.inference_mode()`: lanes serve imagination, which never needs
gradients.
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import torch

MAX_LANES = 2  # the machines this was measured on have 2 cores; more lanes were not measured


class Lanes:
    """`count` threads, each with one intra-op thread, that run calls handed to `run`."""

    def __init__(self, count: int) -> None:
        self.count = count
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        threads = torch.get_num_threads()
        ready = threading.Barrier(count + 1)
        for i in range(count):
            threading.Thread(target=self._serve, args=(ready,), name=f"lwm-lane-{i}", daemon=True).start()
        ready.wait()
        # set_num_threads(1) in a lane also set the process's default for threads that start
        # later (torch reads it when a thread first runs an op): give it back.
        torch.set_num_threads(threads)

    def _serve(self, ready: threading.Barrier) -> None:
        torch.get_num_threads()  # torch's per-thread set-up first, or it would undo the 1 below
        torch.set_num_threads(1)
        ready.wait()
        while True:
            call, args, future = self._jobs.get()
            try:
                with torch.inference_mode():
                    future.set_result(call(*args))
            except BaseException as exc:  # the caller re-raises it
                future.set_exception(exc)

    def run(self, calls: list[tuple[Callable[..., Any], tuple]]) -> list:
        """Run every (function, arguments) on the lanes at once; their results, in order. An
        exception in any is raised here once all have finished."""
        futures = []
        for call, args in calls:
            future: Future = Future()
            self._jobs.put((call, args, future))
            futures.append(future)
        for future in futures:
            future.exception()  # wait for all before raising any: they share the caller's tensors
        return [future.result() for future in futures]


_lanes: Lanes | None = None
_owner = -1  # the process that started them (a forked child has none of their threads)
_lock = threading.Lock()


def lanes() -> Lanes | None:
    """The process's lanes, started on first use; None on a machine with one core."""
    global _lanes, _owner
    with _lock:
        if _owner != os.getpid():
            cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
            count = min(MAX_LANES, cores)
            _lanes = Lanes(count) if count > 1 else None
            _owner = os.getpid()
        return _lanes


__all__ = ["MAX_LANES", "Lanes", "lanes"]

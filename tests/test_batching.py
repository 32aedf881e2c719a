"""Continuous batching of /lwm/imagine (lwm_models.world.continuous and .imagine_server), with real
threads and the shipped model: concurrent requests share the model's steps, join a running batch
and leave it at their own end, and each gets the answer it would get alone."""

from __future__ import annotations

import json
import threading
import time

import pytest
from game_fixtures import MANUAL, OBS, shipped_server

from lwm_models.world.continuous import ContinuousBatch, run_alone
from lwm_models.world.imagine_server import ImagineServer, ShuttingDown, WorkerImagineServer


@pytest.fixture(scope="module")
def sim():
    return shipped_server()


def request(i: int, **extra) -> str:
    actions = [[(i + k) % 5 for k in range(4)], [(2 * i + k) % 5 for k in range(6)]]
    return json.dumps({"version": 1, "observation": OBS, "actions": actions, "max_steps": 8, "seed": i, **extra})


def trajectories(answer: str) -> list[dict]:
    return [
        {k: t[k] for k in ("observations", "actions", "rewards", "dones")} for t in json.loads(answer)["trajectories"]
    ]


def concurrently(server, texts: dict) -> dict:
    """Each request string served from a thread of its own, all released at once: {key: (answer, error)}."""
    results: dict = {}
    gate = threading.Barrier(len(texts))

    def client(key, text: str) -> None:
        gate.wait()
        results[key] = server.serve(text)

    threads = [threading.Thread(target=client, args=item) for item in texts.items()]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    return results


def test_concurrent_requests_share_batches_and_get_what_they_get_alone(sim):
    alone = {i: sim.handle(json.loads(request(i))) for i in range(12)}
    server = ImagineServer(sim)
    results = concurrently(server, {i: request(i) for i in range(12)})
    server.close()
    assert all(error is None for _, error in results.values())
    answers = {i: answer for i, (answer, _) in results.items()}
    assert sorted(answers) == list(range(12))
    for i, answer in answers.items():
        got = json.loads(answer)
        assert got["ok"] and got["manual_version"] == sim.manual_version
        assert trajectories(answer) == trajectories(json.dumps(alone[i])), f"request {i} differs when batched"
    # Requests shared steps: more trajectory-steps were imagined than steps were taken.
    assert server.requests == 12 and server.batch.row_steps > server.batch.steps
    assert max(json.loads(a)["batched"] for a in answers.values()) > 1


def test_a_bad_request_in_a_batch_fails_alone(sim):
    server = ImagineServer(sim)
    bad = json.dumps({"version": 1, "observations": [OBS, OBS], "n": 3, "max_steps": 4})  # 2 starts, 3 trajectories
    results = concurrently(server, {"bad": bad, **{f"good{i}": request(i) for i in range(3)}})
    server.close()
    answer, error = results["bad"]
    assert error is not None and not json.loads(answer)["ok"] and "one per trajectory" in json.loads(answer)["error"]
    for i in range(3):
        answer, error = results[f"good{i}"]
        assert error is None and json.loads(answer)["ok"]


def test_requests_join_a_running_batch_and_leave_at_their_own_end(sim):
    # Requests with other manuals, temperatures and time limits share one batch; one joins after
    # three steps of the others, each at its own place in the KV cache.
    other_manual = [MANUAL[2], MANUAL[0], MANUAL[1]]
    requests = [
        json.loads(request(0, max_steps=12)),
        json.loads(request(1, temperature=0.5, manual=other_manual)),
        json.loads(request(2, max_steps=3)),
    ]
    alone = [run_alone(sim.model, sim.one_shot(r)) for r in requests]
    batch = ContinuousBatch(sim.model)
    shots = [sim.one_shot(r) for r in requests]
    batch.admit(shots[0])
    batch.admit(shots[1])
    ended = []
    for _ in range(3):
        ended += batch.step()
    assert shots[0].t == 3 and not ended
    batch.admit(shots[2])
    while batch:
        ended += batch.step()
    assert shots[2] in ended and shots[2].t == 3  # the short one left at its own time limit
    assert shots[2].peak >= 2 and batch.row_steps > batch.steps
    for shot, want in zip(shots, alone):
        got = shot.result()
        for name in ("observations", "actions", "rewards", "dones", "lengths"):
            assert (getattr(got, name) == getattr(want, name)).all(), name
        assert abs(got.token_probs - want.token_probs).max() < 1e-4


def test_a_big_request_waits_for_room_and_session_ops_are_not_queued(sim):
    server = ImagineServer(sim, max_trajectories=3)
    assert server.batch.fits(5)  # an empty batch takes any request
    answers: dict[int, dict] = {}

    def client(i: int, k: int) -> None:
        text = json.dumps({"version": 1, "observation": OBS, "n": k, "max_steps": 6, "seed": i})
        answers[i] = json.loads(server.serve(text)[0])

    threads = [threading.Thread(target=client, args=(i, k)) for i, k in enumerate((2, 2, 5))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert all(a["ok"] for a in answers.values()) and [len(answers[i]["trajectories"]) for i in range(3)] == [2, 2, 5]
    # 2 + 5 trajectories exceed the limit of 3: the big request ran alone, in an empty batch.
    assert answers[2]["batched"] == 1 and server.batch.widest == 5
    # Session ops are never queued: they are answered in the caller's thread.
    opened, error = server.serve(json.dumps({"version": 1, "op": "open", "observation": OBS, "n": 1, "max_steps": 2}))
    server.close()
    assert error is None and json.loads(opened)["session"] and server.requests == 3


def test_closing_answers_the_waiting_requests_at_once(sim):
    # A node stopping under load: the batch being imagined finishes, the queued ones get an error
    # now (not after their turn), and new ones are refused.
    server = ImagineServer(sim)
    results = []

    def client(i: int) -> None:
        results.append((i, *server.serve(request(i))))

    with sim.lock:  # the worker blocks on its first batch (request 0) until the server is closed
        threads = [threading.Thread(target=client, args=(0,))]
        threads[0].start()
        # Request 0 handed over and taken off the queue by the worker, which now waits for the lock.
        assert wait_until(lambda: server.submitted == 1 and server._queue.empty())
        threads += [threading.Thread(target=client, args=(i,)) for i in range(1, 6)]
        for t in threads[1:]:
            t.start()
        assert wait_until(lambda: server.submitted == 6)  # requests 1-5 wait in the queue
        closing = threading.Thread(target=server.close)
        closing.start()
        assert wait_until(lambda: server._closed.is_set())
    began = time.perf_counter()
    for t in threads:
        t.join(10)
    closing.join(10)
    assert time.perf_counter() - began < 5 and len(results) == 6
    answers = {i: (json.loads(text), error) for i, text, error in results}
    assert answers[0][1] is None and answers[0][0]["ok"]  # the batch being imagined finishes
    for i in range(1, 6):
        assert answers[i][1] is not None and "shutting down" in answers[i][0]["error"]
    text, error = server.serve(request(9))
    assert error is not None and "shutting down" in json.loads(text)["error"]


@pytest.fixture(scope="module")
def worker_server(sim):
    server = WorkerImagineServer(sim)
    yield server
    server.close()


def test_the_worker_process_answers_as_the_thread_does_and_batches(sim, worker_server):
    # The world-model server node's server: the same answers as a call alone, while concurrent calls share
    # the worker process's steps.
    alone = {i: sim.handle(json.loads(request(i))) for i in range(8)}
    results = concurrently(worker_server, {i: request(i) for i in range(8)})
    assert sorted(results) == list(range(8)) and all(error is None for _, error in results.values())
    answers = {i: answer for i, (answer, _) in results.items()}
    for i, answer in answers.items():
        assert trajectories(answer) == trajectories(json.dumps(alone[i])), f"request {i} differs in the worker"
    assert max(json.loads(a)["batched"] for a in answers.values()) > 1
    bad, error = worker_server.serve(json.dumps({"version": 1, "observations": [OBS, OBS], "n": 3, "max_steps": 4}))
    assert error is not None and "one per trajectory" in json.loads(bad)["error"]


def test_a_killed_worker_fails_its_calls_and_is_started_again(sim):
    server = WorkerImagineServer(sim)
    try:
        results = []
        long_call = json.dumps({"version": 1, "observation": OBS, "n": 256, "max_steps": 32, "seed": 1})
        caller = threading.Thread(target=lambda: results.append(server.serve(long_call)))
        caller.start()
        while not server.workers[0].load:  # the call has been sent to the worker (it takes about 2 s)
            time.sleep(0.01)
        first = server.workers[0].proc
        first.kill()
        caller.join(30)
        text, error = results[0]
        assert error is not None and "worker stopped" in json.loads(text)["error"]
        deadline = time.time() + 30
        while server.restarts < 1 and time.time() < deadline:
            time.sleep(0.1)
        text, error = server.serve(request(3))
        assert error is None and json.loads(text)["ok"] and server.workers[0].proc is not first and server.restarts == 1
    finally:
        server.close()
    assert server.workers[0].proc.poll() is not None  # closing ended the worker process
    text, error = server.serve(request(4))
    assert error is not None and "shutting down" in json.loads(text)["error"]


def test_closing_the_worker_server_answers_every_call_within_its_deadline(sim):
    # Five calls of 256 trajectories each (a batch's limit: each runs alone, about 1-2 s): the
    # first is being imagined, the others wait in the worker. Closing with a 0.3 s deadline answers
    # every call at once; the waiting ones (all, or all but one that the first left room for) are
    # refused. The test waits for the calls to reach the worker (an event), not for a time.
    server = WorkerImagineServer(sim)
    big = [json.dumps({"version": 1, "observation": OBS, "n": 256, "max_steps": 32, "seed": i}) for i in range(5)]
    results: dict[int, tuple[str, Exception | None]] = {}

    def call(i: int) -> threading.Thread:
        thread = threading.Thread(target=lambda: results.__setitem__(i, server.serve(big[i])))
        thread.start()
        return thread

    def in_worker() -> int:
        with server.workers[0].lock:
            return len(server.workers[0].jobs)

    threads = [call(0)]
    assert wait_until(lambda: in_worker() == 1)
    threads += [call(i) for i in range(1, 5)]
    assert wait_until(lambda: in_worker() == 5)
    began = time.perf_counter()
    server.close(timeout=0.3)
    for t in threads:
        t.join(10)
    took = time.perf_counter() - began
    # The bound is the world-model server node's: it must have stopped 2 s after the signal. Measured (20
    # closes while scripts/stress_ci.sh ran the suite beside a CPU burner): median 0.54 s, max 0.98 s.
    assert took < 2.0 and sorted(results) == [0, 1, 2, 3, 4], (took, sorted(results))
    refused = [i for i, (text, error) in results.items() if error is not None and "shutting down" in text]
    answered = [i for i, (text, error) in results.items() if error is None and json.loads(text)["ok"]]
    assert len(refused) + len(answered) == 5, {i: text[:120] for i, (text, _) in results.items()}
    assert len([i for i in refused if i > 0]) >= 3
    assert server.workers[0].proc.wait(5) is not None  # ended: answered and stopped, or killed


def test_a_call_after_close_is_refused_as_shutting_down_not_as_a_lost_worker(sim):
    server = WorkerImagineServer(sim)
    server.close(timeout=0.3)
    text, error = server.serve(request(1))
    assert isinstance(error, ShuttingDown) and "shutting down" in json.loads(text)["error"]


def wait_until(predicate, timeout: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.005)
    return bool(predicate())

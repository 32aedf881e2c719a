"""The lanes (lwm_models/world/lanes.py): threads that step groups of imagined rows side by side."""

from __future__ import annotations

import threading
import time

import pytest
import torch

from lwm_models.world.lanes import Lanes


def test_lanes_run_at_once_on_one_intra_op_thread_each_and_leave_the_caller_s_setting():
    before = torch.get_num_threads()
    lanes = Lanes(2)
    assert torch.get_num_threads() == before
    started = threading.Barrier(2, timeout=5)  # both calls must be running at the same time

    def job(i: int) -> tuple:
        started.wait()
        return i, torch.get_num_threads(), torch.is_inference_mode_enabled(), threading.current_thread().name

    results = lanes.run([(job, (0,)), (job, (1,))])
    assert [r[0] for r in results] == [0, 1]  # in the order given
    assert all(r[1] == 1 and r[2] for r in results)
    assert len({r[3] for r in results}) == 2
    assert torch.get_num_threads() == before


def test_an_error_in_one_lane_is_raised_after_every_lane_has_finished():
    lanes = Lanes(2)
    finished = []

    def fails() -> None:
        raise ValueError("bad rows")

    def slow() -> None:
        time.sleep(0.3)
        finished.append(True)

    with pytest.raises(ValueError, match="bad rows"):
        lanes.run([(fails, ()), (slow, ())])
    assert finished == [True]  # the caller's tensors were not released while a lane still used them
    assert lanes.run([(lambda: 7, ())]) == [7]  # and the lanes still serve

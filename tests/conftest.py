"""Test ordering for two workers: files that start whole ROS systems (marked `system`) are handed
out first. run_tests.sh gives each worker whole files (`--dist loadfile`), so starting the long ones
early lets the short files fill in around them instead of one worker finishing a long file alone."""

from __future__ import annotations

import os

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "system: starts the whole ROS system in processes (tens of seconds each)")
    if os.environ.get("PYTEST_XDIST_WORKER"):
        # Two workers on two cores: torch's default of a thread per core would put four spinning
        # threads on two cores, and an in-process test then ran 54x slower (measured).
        # Processes the tests start inherit the setting unless they choose their own.
        os.environ["OMP_NUM_THREADS"] = "1"
        import torch

        torch.set_num_threads(1)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items.sort(key=lambda item: item.get_closest_marker("system") is None)  # stable: files stay in order

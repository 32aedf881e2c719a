#!/usr/bin/env bash
# Set up .venv if needed, then run the test suite on two workers. Extra arguments go to pytest.
set -euo pipefail
cd "$(dirname "$0")"
scripts/setup_venv.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
# Two workers, each given whole test files (module fixtures start one system per file); about half
# the suite's time is spent waiting on processes and DDS, so two workers on two cores take much
# less wall time than one. `./run_tests.sh -n 0` runs it in one process.
exec .venv/bin/python -m pytest -n "${LWM_TEST_WORKERS:-2}" --dist loadfile "$@"

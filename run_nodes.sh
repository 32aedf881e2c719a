#!/usr/bin/env bash
# Start the LWM system: set up .venv if needed, then launch the nodes under a supervisor
# (lwm_nodes.launcher): the Messenger environment, the world-model server serving /lwm/imagine on the
# shipped EMMA-LWM, the planner and, in a terminal, the interactive human-feedback node.
# --scripted runs the review loop with the simulated human and exits with a summary.
# Options: ./run_nodes.sh --help. Stop with Ctrl-C.
set -euo pipefail
cd "$(dirname "$0")"
scripts/setup_venv.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
exec .venv/bin/python -m lwm_nodes.launcher "$@"

#!/usr/bin/env bash
# Start the LWM system: set up .venv if needed, then launch the nodes under a supervisor
# (lwm_nodes.launcher): the Messenger environment and the LWM simulator serving /lwm/imagine on
# the shipped EMMA-LWM. Options: ./run_nodes.sh --help. Stop with Ctrl-C.
set -euo pipefail
cd "$(dirname "$0")"
scripts/setup_venv.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-LOCALHOST}"
exec .venv/bin/python -m lwm_nodes.launcher "$@"

#!/usr/bin/env bash
# Start the LWM system's ROS 2 nodes. The nodes are not built yet (see the ROS 2 system issue);
# for now this sets up the environment and says so.
set -euo pipefail
cd "$(dirname "$0")"
scripts/setup_venv.sh
echo "run_nodes: the ROS 2 nodes are not built yet. The core is ready: try '.venv/bin/lwm play' or '.venv/bin/lwm data splits'." >&2
exit 1

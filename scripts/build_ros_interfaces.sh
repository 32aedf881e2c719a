#!/usr/bin/env bash
# Build ros_ws/src/lwm_interfaces (the service types) and install it into .venv, idempotently.
# Why each step is needed: docs/ros.md, "Building the service type".
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="$root/.venv"
pkg="$root/ros_ws/src/lwm_interfaces"
want="$(cat "$root/requirements-ros-build.txt" "$root/scripts/build_ros_interfaces.sh" "$pkg"/package.xml \
  "$pkg"/CMakeLists.txt "$pkg"/srv/*.srv | sha256sum | cut -d' ' -f1)"
stamp="$venv/.ros-interfaces-stamp"
if [[ -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
  exit 0
fi
echo "setup: building the ROS 2 service types (about a minute)" >&2
"$venv/bin/python" -m pip --disable-pip-version-check -q install -r "$root/requirements-ros-build.txt" \
  2> >(grep -v "^WARNING: Location 'file://" >&2 || true)

# The wheels' CMake files name the wheel builder's Python include dirs; point them at ours.
"$venv/bin/python" - "$venv" <<'PY'
import pathlib, sys, sysconfig
import numpy
venv = pathlib.Path(sys.argv[1])
ours_py = sysconfig.get_paths()["include"]
ours_np = numpy.get_include()
for f in (venv / "share").rglob("*.cmake"):
    text = f.read_text(errors="surrogateescape")
    new = text
    for old in ("/opt/python/cp311-cp311/include/python3.11",):
        new = new.replace(old, ours_py)
    if "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy" in new:
        import re
        new = re.sub(r"/opt/python/cp311-cp311/lib/python3\.11/site-packages/numpy/[\w/]*include", ours_np, new)
    if new != text:
        f.write_text(new, errors="surrogateescape")
PY

build="$root/ros_ws/build/lwm_interfaces"
rm -rf "$build"
mkdir -p "$build"
export AMENT_PREFIX_PATH="$venv"
export PATH="$venv/bin:$PATH"
cmake -S "$pkg" -B "$build" -DCMAKE_INSTALL_PREFIX="$venv" -DBUILD_TESTING=OFF \
  -DPython3_EXECUTABLE="$venv/bin/python" > "$build/configure.log" 2>&1 \
  || { tail -40 "$build/configure.log" >&2; exit 1; }
cmake --build "$build" -j 2 > "$build/build.log" 2>&1 || { tail -40 "$build/build.log" >&2; exit 1; }
cmake --install "$build" > "$build/install.log" 2>&1 || { tail -40 "$build/install.log" >&2; exit 1; }
"$venv/bin/python" -c "from lwm_interfaces.srv import Json" \
  || { echo "setup: lwm_interfaces built but does not import" >&2; exit 1; }
echo "$want" > "$stamp"
echo "setup: ROS 2 service types installed" >&2

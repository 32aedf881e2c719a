#!/usr/bin/env bash
# Run the whole test suite N times while a CPU burner holds one core, then print the failures per
# test and the slowest tests. What CI must survive: a loaded 2-core machine.
#
#   scripts/stress_ci.sh 10                      # the figure docs/testing.md quotes
#   scripts/stress_ci.sh 3 -k "ros or batching"  # extra arguments go to pytest
#
# Each run's JUnit XML and output go to a directory of its own (default ~/.cache/lwm-stress/<time>,
# outside the repository; STRESS_DIR=... to choose); the report is printed and written there as
# report.txt. Exit status: 0 when every run passed, 1 otherwise.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$root"
n="${1:?usage: scripts/stress_ci.sh N [pytest args...]}"
shift
if ! [[ "$n" =~ ^[1-9][0-9]*$ ]]; then
  echo "stress_ci: N must be a positive integer, not '$n'" >&2
  exit 2
fi
out="${STRESS_DIR:-$HOME/.cache/lwm-stress/$(date -u +%Y%m%dT%H%M%S)}"
mkdir -p "$out"
scripts/setup_venv.sh

# The burner: one busy process, one core's worth of load for the whole run.
python3 -c "while True: pass" &
burner=$!
trap 'kill "$burner" 2>/dev/null || true' EXIT

failed_runs=0
for i in $(seq 1 "$n"); do
  began=$(date +%s)
  if ./run_tests.sh -q -p no:cacheprovider --junitxml="$out/run-$i.xml" "$@" > "$out/run-$i.log" 2>&1; then
    result=passed
  else
    result=FAILED
    failed_runs=$((failed_runs + 1))
  fi
  echo "stress_ci: run $i/$n $result in $(( $(date +%s) - began )) s: $(tail -n 1 "$out/run-$i.log")"
done
kill "$burner" 2>/dev/null || true
.venv/bin/python scripts/stress_ci_report.py "$out" | tee "$out/report.txt"
[ "$failed_runs" -eq 0 ]

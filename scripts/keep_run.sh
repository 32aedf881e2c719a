#!/usr/bin/env bash
# Commit the resumable state of a long run (runs/long-KIND: last/, best/, metrics.jsonl, the log),
# so that the next session, on a new machine with a fresh work tree, resumes it exactly with
# scripts/long_run.sh KIND. Refuses while the run is training or mid-save (a last.new or last.old
# beside last/ means a checkpoint swap is under way or was cut off: lwm train finishes it).
#
#   scripts/keep_run.sh KIND [MESSAGE]
set -euo pipefail
cd "$(dirname "$0")/.."
kind=${1:?usage: scripts/keep_run.sh KIND [MESSAGE]}
out=runs/long-$kind
[ -f "$out/last/train_state.json" ] || { echo "keep_run: no run state in $out/last" >&2; exit 2; }
if pgrep -f -- "--out $out " > /dev/null; then
    echo "keep_run: $out is still training; wait for its chunk to end" >&2
    exit 2
fi
for d in "$out"/last.new "$out"/last.old "$out"/best.new "$out"/best.old; do
    [ -e "$d" ] && { echo "keep_run: $d exists (a swap was cut off); resume the run to finish it" >&2; exit 2; }
done
step=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['step'])" "$out/last/train_state.json")
git add -A -- "$out" "runs/long-$kind.log"
git commit -q -m "${2:-Long run $kind: state at step $step}" -- "$out" "runs/long-$kind.log"
echo "keep_run: committed $out at step $step"

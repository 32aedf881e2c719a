#!/usr/bin/env bash
# One chunk of a long world-model run, started again each session until its CPU budget is spent:
# the same command resumes exactly from RUN/last (see docs/world-models.md, "Training in chunks").
#
#   scripts/long_run.sh RECIPE [MAX_MINUTES]   RECIPE: emma-lwm observational standard gpthard oracle-long
#
# The recipe is configs/RECIPE.json (lwm train --config): the same for every kind, so that their
# figures compare. MAX_MINUTES (default 145) ends this chunk with an evaluation and a save.
# The code that trains is a git worktree of a fixed commit (CODE_COMMIT, default the commit checked
# out when the first chunk starts, in runs/code-long), so that work on main does not change a run
# half-way. The run lives in the recipe's `out` (runs/long-KIND), which git ignores: keep runs/ on a
# disk that outlives the session to resume it.
# Runs in the background; progress in runs/long-KIND.log and runs/long-KIND/metrics.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."

CODE_COMMIT=${CODE_COMMIT:-$(git rev-parse --short HEAD)}
recipe=${1:?usage: scripts/long_run.sh RECIPE [MAX_MINUTES]}
minutes=${2:-145}
config=configs/$recipe.json
[ -f "$config" ] || { echo "long_run: no recipe $config" >&2; exit 2; }
scripts/setup_venv.sh
option() { .venv/bin/python -c "import json, sys; print(json.load(open(sys.argv[1]))['options'][sys.argv[2]])" "$config" "$1"; }
DATA=$(option data)
out=$(option out)
if [ ! -f "$DATA/index.json" ]; then
    # The dataset is seeded: generating it again on a new machine gives the run the same data.
    texts=../shared/data/messenger-texts
    if [ "$DATA" = data/human ] && [ -f "$texts/text_train.json" ]; then
        .venv/bin/lwm data generate --out "$DATA" --text-source "$texts/text_train.json" "$texts/text_val.json" > /dev/null
    else
        echo "long_run: no dataset at $DATA (see docs/world-models.md: lwm data generate)" >&2
        exit 2
    fi
fi
code=runs/code-long
if [ ! -d "$code" ]; then
    git worktree add -f "$code" "$CODE_COMMIT"
    for d in .venv data runs; do ln -s "../../$d" "$code/$d"; done
fi
if pgrep -f -- "--config $config " > /dev/null; then
    echo "long_run: $out is already training" >&2
    exit 2
fi
cmd=(.venv/bin/python -m lwm_models.cli.main train --config "$config" --max-minutes "$minutes" --no-progress)
mkdir -p "$out"
echo "${cmd[*]}" > "$out/cmd.txt"
echo "$(date -Is) long_run: $recipe at $CODE_COMMIT, chunk of at most $minutes minutes" >> "$out.log"
(cd "$code" && nohup "${cmd[@]}" >> "$out.log" 2>&1 &)
echo "long_run: $recipe started in the background (log: $out.log)"

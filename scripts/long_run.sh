#!/usr/bin/env bash
# One chunk of a long world-model run, started again each session until its CPU budget
# is spent: the same command resumes exactly from RUN/last (`lwm train`, see README "Long runs").
#
#   scripts/long_run.sh KIND [MAX_MINUTES]     KIND: emma observational standard gpthard oracle
#
# The recipe is the pilot's winner (results/pilot_partial.txt: lr 1e-3 beat 5e-4 at equal CPU
# time), for every kind alike so that their figures compare: small preset, lr 1e-3, warm-up 300,
# cosine to 60,000 steps, batches in 4 parts of similar-length segments (lwm train --parts: the
# same gradient as one padded batch at ~2.8x the steps per CPU-hour), one thread, NewAll-dev every
# 1,000 steps on 1,500 episodes, 8 CPU-hours at most.
# The code that trains is a git worktree of a fixed commit (CODE_COMMIT, in runs/code-long), so
# that work on main does not change a run half-way. The run lives in runs/long-KIND, which git
# ignores: keep runs/ on a disk that outlives the session to resume it. MAX_MINUTES (default 145)
# ends this chunk with an evaluation and a save.
# Runs in the background; progress in runs/long-KIND.log and runs/long-KIND/metrics.jsonl.
set -euo pipefail
cd "$(dirname "$0")/.."

CODE_COMMIT=${CODE_COMMIT:-12bf308}
DATA=${DATA:-data/human}
kind=${1:?usage: scripts/long_run.sh KIND [MAX_MINUTES]}
minutes=${2:-145}
case "$kind" in
    emma | observational | standard | gpthard | oracle) ;;
    *) echo "long_run: unknown kind $kind (emma observational standard gpthard oracle)" >&2; exit 2 ;;
esac
scripts/setup_venv.sh
if [ ! -f "$DATA/index.json" ]; then
    # The dataset is seeded: generating it again on a new machine gives the run the same data.
    texts=../shared/data/messenger-texts
    if [ "$DATA" = data/human ] && [ -f "$texts/text_train.json" ]; then
        .venv/bin/lwm data generate --out "$DATA" --text-source "$texts/text_train.json" "$texts/text_val.json" > /dev/null
    else
        echo "long_run: no dataset at $DATA (see README: lwm data generate)" >&2
        exit 2
    fi
fi
code=runs/code-long
if [ ! -d "$code" ]; then
    git worktree add -f "$code" "$CODE_COMMIT"
    for d in .venv data runs; do ln -s "../../$d" "$code/$d"; done
fi
out=runs/long-$kind
if pgrep -f -- "--out $out " > /dev/null; then
    echo "long_run: $out is already training" >&2
    exit 2
fi
cmd=(.venv/bin/python -m lwm_models.cli.main train --data "$DATA" --out "$out" --kind "$kind" --preset small
     --steps 60000 --lr 1e-3 --warmup 300 --cosine --parts 4 --threads 1 --eval-every 1000 --eval-episodes 1500
     --cpu-budget-minutes 480 --max-minutes "$minutes" --no-progress)
mkdir -p "$out"
echo "${cmd[*]}" > "$out/cmd.txt"
echo "$(date -Is) long_run: $kind at $CODE_COMMIT, chunk of at most $minutes minutes" >> "runs/long-$kind.log"
(cd "$code" && nohup "${cmd[@]}" >> "runs/long-$kind.log" 2>&1 &)
echo "long_run: $kind started in the background (log: runs/long-$kind.log)"

#!/usr/bin/env bash
# Pilot for the long world-model training (issue 10): EMMA-LWM recipes compared at equal time.
# Each variant trains for a budget of CPU minutes (default 40) on ONE thread, one variant after
# another (never two at once), into runs/pilot-<name>/ (metrics.jsonl, log, cmd.txt, time.txt).
# CPU time, not wall-clock, so that work in the foreground on the other core does not shorten a
# variant; the budget counts over chunks, so a variant cut off by the end of a session resumes
# exactly where its last checkpoint left it (`lwm train --cpu-budget-minutes`).
#
# Measured on this machine (AMD EPYC, AVX2 only, no AVX512-BF16/AMX; PyTorch 2.13.0+cpu, whose
# oneDNN bf16 path is unavailable here) with the shipped recipe, small preset, 1 thread:
#   bf16 autocast 15.6 s/step (first 50 steps; the bf16 matmuls fall back to a slow reference
#   GEMM), fp32 1.7-2.1 s/step in a 3-minute test and a median 1.36 s/step over the first 1,000
#   steps of the base run (the other core's load varies). The shipped runs reached 0.7 s/step with
#   bf16 on another CPU.
# So the base of this pilot is the shipped recipe in fp32; bf16 is an optional variant (at equal
# time it reaches ~1/8 of the steps here). 40 minutes (1,200-1,700 fp32 steps) get past step ~1,000,
# where EMMA-LWM starts to use the manual (the shipped run: dev 1.49 at step 500, 0.32 at 1,000).
#
# All variants share the cosine schedule of a long run (--steps STEPS = 14,400: 8 CPU-hours at the
# 2 s/step of the first test; at 1.36 s/step 8 hours are ~21,000 steps, which changes the lr of the
# pilot's first 1,700 steps by under 2%), so each pilot covers the same early part of that schedule.
# Variants (default order, most informative first):
#   base       small preset (multi-query: 1 KV head; attention dropout 0), lr 5e-4, warm-up 300,
#              cosine, fp32
#   mha        base with 4 key/value heads (full multi-head attention)
#   attndrop   base with attention-probability dropout 0.1
#   lr1e-3     base with lr 1e-3
#   seed1      base with seed 1 (how far two seeds differ: the noise floor of the comparison)
#   bf16       base with bf16 autocast, i.e. the shipped recipe (not in the default list)
#
# A variant with a DONE marker is skipped; a variant left unfinished (no DONE) resumes.
# The code that trains is that of the checkout this script lives in (python -m from its root), so
# the pilot can run from a worktree of a fixed commit while the main checkout changes:
#   git worktree add runs/code-pilot <commit>; ln -s ../../{.venv,data,runs} runs/code-pilot/
#   nohup runs/code-pilot/scripts/pilot.sh > runs/pilot.log 2>&1 &
#
# Usage: scripts/pilot.sh [variant ...]     (default: base mha attndrop lr1e-3 seed1)
#   env: DATA (data/human), MINUTES (40 CPU minutes), STEPS (14400), EVAL_EVERY (250), EVAL_EPISODES (500)
# Progress: .venv/bin/python scripts/pilot_report.py; runs/pilot.log; runs/pilot-*/log
# While it runs, change this file only by replacing it (write a copy, then mv): bash reads a
# running script from its file as it goes.
set -u
cd "$(dirname "$0")/.."

DATA=${DATA:-data/human}
MINUTES=${MINUTES:-40}
STEPS=${STEPS:-14400}
EVAL_EVERY=${EVAL_EVERY:-250}
EVAL_EPISODES=${EVAL_EPISODES:-500}
ALL=(base mha attndrop lr1e-3 seed1)
OPTIONAL=(bf16)

common=(--kind emma --preset small --steps "$STEPS" --lr 5e-4 --warmup 300 --cosine --threads 1
        --eval-every "$EVAL_EVERY" --eval-episodes "$EVAL_EPISODES" --cpu-budget-minutes "$MINUTES" --no-progress)

variant_args() {
    case "$1" in
        base) echo "--no-bf16" ;;
        mha) echo "--no-bf16 --kv-heads 4" ;;
        attndrop) echo "--no-bf16 --attn-dropout 0.1" ;;
        lr1e-3) echo "--no-bf16 --lr 1e-3" ;;
        seed1) echo "--no-bf16 --seed 1" ;;
        bf16) echo "--bf16" ;;
        *) return 1 ;;
    esac
}

if [ ! -f "$DATA/index.json" ]; then
    echo "pilot: no dataset at $DATA (run: .venv/bin/lwm data generate --out $DATA ...)" >&2
    exit 2
fi

names=("$@")
[ ${#names[@]} -eq 0 ] && names=("${ALL[@]}")
for name in "${names[@]}"; do
    if ! extra=$(variant_args "$name"); then
        echo "pilot: unknown variant $name (known: ${ALL[*]} ${OPTIONAL[*]})" >&2
        exit 2
    fi
    out=runs/pilot-$name
    if [ -f "$out/DONE" ]; then
        echo "$(date -Is) pilot: $name already done, skipped"
        continue
    fi
    [ -e "$out/last" ] && echo "$(date -Is) pilot: $name was unfinished, resuming"
    mkdir -p "$out"
    # shellcheck disable=SC2206
    cmd=(.venv/bin/python -m lwm_models.cli.main train --data "$DATA" --out "$out" "${common[@]}" $extra)
    echo "${cmd[*]}" > "$out/cmd.txt"
    echo "$(date -Is) pilot: start $name at $(git rev-parse --short HEAD): ${cmd[*]}"
    /usr/bin/time -v -a -o "$out/time.txt" "${cmd[@]}" >> "$out/log" 2>&1
    rc=$?
    if [ $rc -eq 0 ]; then
        date -Is > "$out/DONE"
        echo "$(date -Is) pilot: $name done"
    else
        echo "$(date -Is) pilot: $name FAILED (exit $rc), see $out/log"
    fi
done
echo "$(date -Is) pilot: finished"

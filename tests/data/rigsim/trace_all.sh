#!/bin/sh
# Trace every committed rig-sim run as a user does (thsa trace RUN.csv --model A), two at a time, into DIR/RUN;
# then `THSA_TRACED_DIR=DIR python -m pytest -m campaign tests/test_trace_foreign.py` judges those traces and
# `python bench/trace_rigsim_table.py DIR/*` tabulates them. The run sets (sets/, traced together) have their own
# script, trace_sets.sh, and tests (tests/test_trace_sets.py, THSA_TRACED_SETS_DIR).
# Usage: tests/data/rigsim/trace_all.sh DIR [PARALLEL]
set -e
out=${1:?usage: trace_all.sh DIR [PARALLEL]}
par=${2:-2}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
ls "$here"/*.csv | xargs -P "$par" -I{} sh -c 'n=$(basename "{}" .csv); thsa trace "{}" --model A --out "$0/$n" --force --quiet > "$0/$n.log" 2>&1 || echo "$n: exit $?" >&2' "$out"

#!/bin/sh
# Trace every committed rig-sim run set (sets/SET_*.csv, several runs of one rig) jointly as a user does
# (thsa trace SET_1.csv SET_2.csv --model A), one set at a time, into DIR/SET; then
# `THSA_TRACED_SETS_DIR=DIR python -m pytest -m campaign tests/test_trace_sets.py` judges those traces.
# Usage: tests/data/rigsim/trace_sets.sh DIR
set -e
out=${1:?usage: trace_sets.sh DIR}
here=$(cd "$(dirname "$0")" && pwd)
mkdir -p "$out"
for s in $(ls "$here"/sets/*_1.csv | sed 's/_1\.csv$//'); do
    n=$(basename "$s")
    thsa trace "$s"_[0-9].csv --model A --out "$out/$n" --force --quiet > "$out/$n.log" 2>&1 || echo "$n: exit $?" >&2
done

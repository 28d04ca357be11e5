#!/usr/bin/env bash
# Instructions per particle-step of `repose bench engine` (1 thread), counted by callgrind, so
# the figure does not depend on how loaded the machine is. The settle phase is identical in two
# runs of the same binary, so the difference between a run of STEPS2 and one of STEPS1 timed
# steps, divided by (STEPS2 - STEPS1) x particles, is the cost of the timed steps alone.
#
#   bash bench/instructions/run.sh path/to/repose [more binaries...]
#   N=5000 STEPS1=20 STEPS2=60 bash bench/instructions/run.sh old/repose new/repose
set -euo pipefail
N="${N:-5000}"
STEPS1="${STEPS1:-20}"
STEPS2="${STEPS2:-60}"
command -v valgrind >/dev/null || {
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq valgrind >/dev/null
}
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
count() { # binary steps -> total instructions (Ir) of the whole process
    valgrind --tool=callgrind --callgrind-out-file="$work/cg.out" \
        "$1" bench engine --particles "$N" --threads 1 --steps "$2" >/dev/null 2>"$work/err" ||
        { cat "$work/err" >&2; exit 1; }
    grep -a '^summary:' "$work/cg.out" | awk '{print $2}'
}
echo "| binary | particles | Ir (${STEPS1} steps) | Ir (${STEPS2} steps) | instructions / particle-step |"
echo "|---|---|---|---|---|"
for bin in "$@"; do
    a="$(count "$bin" "$STEPS1")"
    b="$(count "$bin" "$STEPS2")"
    per="$(python3 -c "print(f'{($b - $a) / (($STEPS2 - $STEPS1) * $N):.0f}')")"
    echo "| $bin | $N | $a | $b | $per |"
done

#!/usr/bin/env bash
# Does this host give two threads two whole cores? Three checks, each a run alone on vCPU 0
# and then one copy per vCPU at the same time (results: docs/perf-log/2026-11.md, fifteenth session; current figures in BENCHMARKS.md):
#   fp     a C loop of 64 independent multiply-add chains: throughput-bound on the FP units,
#          so two vCPUs that are SMT siblings of one physical core would halve it;
#   chase  a dependent pointer chase through 64 MiB: latency-bound, shares only the memory;
#   engine `repose bench engine --threads 1` (PARTICLES, default 20000): two independent beds,
#          so any slowdown is shared cache or memory, not our parallel code.
#
#   bash bench/smt/run.sh target/release/repose
set -euo pipefail
repose="${1:?usage: bash bench/smt/run.sh path/to/repose}"
particles="${PARTICLES:-20000}"
steps="${STEPS:-2000}"
rounds="${ROUNDS:-2}"
here="$(cd "$(dirname "$0")" && pwd)"
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
cc -O2 -DCH=64 -o "$work/alu" "$here/alu.c"
engine() { # cpu -> M particle-steps/s of one 1-thread bed pinned to that vCPU
    taskset -c "$1" "$repose" bench engine --particles "$particles" --threads 1 \
        --steps "$steps" --json | tail -1 |
        python3 -c 'import json, sys; print("%.2f" % (json.load(sys.stdin)["mega_particle_steps_per_s"]))'
}
kernel() { # kind cpu -> its rate
    case "$1" in
    engine) engine "$2" ;;
    *) taskset -c "$2" "$work/alu" "$1" 4 | awk '{print $2}' ;;
    esac
}
echo "| check | round | alone on vCPU 0 | both at once: vCPU 0 | vCPU 1 |"
echo "|---|---|---|---|---|"
for kind in fp chase engine; do
    for round in $(seq "$rounds"); do
        alone="$(kernel "$kind" 0)"
        kernel "$kind" 0 >"$work/a" &
        kernel "$kind" 1 >"$work/b"
        wait
        echo "| $kind | $round | $alone | $(cat "$work/a") | $(cat "$work/b") |"
    done
done

#!/usr/bin/env bash
# LIGGGHTS side-by-side for repose's engine bench (engine/src/bench.rs). See README.md.
#
#   bash bench/liggghts/run.sh                 # sizes 5000 20000 80000, 1 and 2 MPI ranks
#   SIZES="10000 40000" PROCS="1 2" STEPS=2000 bash bench/liggghts/run.sh
#   REUSE=1 SIZES=5000 bash bench/liggghts/run.sh   # re-time, keeping out/rest_5000.data
#
# Per size: make_bed.py writes the jittered lattice, in.settle collapses it (untimed, on
# SETTLE_PROCS ranks) and writes the bed, then in.bench times STEPS steps of the bed at rest for
# each rank count. Prints a markdown table and writes it to results-<date>.md. Scratch files
# (data files, logs) go to $WORK (default bench/liggghts/out/, git-ignored); no dumps.
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
SIZES="${SIZES:-5000 20000 80000}"
PROCS="${PROCS:-1 2}"
STEPS="${STEPS:-2000}"
SEED="${SEED:-1}"
SETTLE_PROCS="${SETTLE_PROCS:-1}"
WORK="${WORK:-$HERE/out}"
DATE="$(date -u +%Y-%m-%d)"
RESULTS="${RESULTS:-$HERE/results-$DATE.md}"

need=()
command -v liggghts >/dev/null || need+=(liggghts)
command -v mpirun >/dev/null || need+=(openmpi-bin)
[ -x /usr/bin/time ] || need+=(time)
command -v python3 >/dev/null || need+=(python3)
if [ ${#need[@]} -gt 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi

mkdir -p "$WORK"
cd "$WORK"
launch() { # launch NPROCS args...
    local np="$1"; shift
    if [ "$np" -eq 1 ]; then "$@"; else
        mpirun --allow-run-as-root --oversubscribe -np "$np" "$@"; fi
}
load1() { cut -d' ' -f1 /proc/loadavg; }

for n in $SIZES; do
    vars="$(python3 "$HERE/make_bed.py" "$n" "$SEED" "init_$n.data")"
    if [ "${REUSE:-0}" = 1 ] && [ -s "rest_$n.data" ]; then
        echo "== N=$n: reusing the settled bed rest_$n.data (REUSE=1)" >&2
    else
        echo "== N=$n: settling on $SETTLE_PROCS rank(s), load $(load1)" >&2
        t0=$(date +%s)
        # shellcheck disable=SC2086
        launch "$SETTLE_PROCS" liggghts -in "$HERE/in.settle" -var DIR "$HERE" -var DATA "init_$n.data" \
            -var OUT "bed_$n.data" $vars -log "settle_$n.log" -screen none
        settled="$(grep -a '^SETTLED' "settle_$n.log")"
        echo "   $settled ($(( $(date +%s) - t0 )) s wall)" >&2
        # At rest, no contact history: drop the Velocities section.
        sed '/^Velocities/,$d' "bed_$n.data" > "rest_$n.data"
    fi
    for np in $PROCS; do
        load="$(load1)"
        echo "$load" > "load_${n}_$np.txt"
        echo "== N=$n, $np rank(s): timing $STEPS steps, load $load" >&2
        log="bench_${n}_$np.log"
        cmd=(liggghts -in "$HERE/in.bench" -var DIR "$HERE" -var DATA "rest_$n.data" -var STEPS "$STEPS")
        # shellcheck disable=SC2206
        cmd+=($vars -log "$log" -screen none)
        if [ "$np" -gt 1 ]; then cmd=(mpirun --allow-run-as-root --oversubscribe -np "$np" "${cmd[@]}"); fi
        /usr/bin/time -v -o "time_${n}_$np.txt" "${cmd[@]}"
        grep -a '^Loop time' "$log" | sed -n 2p >&2
    done
done

{
    echo "LIGGGHTS $(liggghts -h 2>/dev/null | grep -o 'LIGGGHTS-PUBLIC [0-9.]*') (Debian package $(dpkg-query -W -f='${Version}' liggghts 2>/dev/null)), repose bench bed, $STEPS timed steps, seed $SEED"
    echo
    echo "Machine: $(lscpu | sed -n 's/^Model name: *//p'), $(nproc) cores; $(date -u '+%Y-%m-%d %H:%M UTC')"
    echo
    python3 "$HERE/report.py" "$WORK" "$STEPS" "$SEED"
} > "$RESULTS.tmp"
mv "$RESULTS.tmp" "$RESULTS"
cat "$RESULTS"

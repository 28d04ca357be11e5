#!/usr/bin/env bash
# repose's funnel test in LIGGGHTS 3.8, measured by repose's own measurement. See README.md.
#
#   bash bench/liggghts-funnel/run.sh                                   # paper-scale, 0.3 kg
#   SETS="total_mass=0.002" OUT=/tmp/lf-tiny bash bench/liggghts-funnel/run.sh   # a tiny check
#   ALSO_REPOSE=1 THREADS=2 bash bench/liggghts-funnel/run.sh           # and repose beside it
#
# Environment: REPOSE (the repose binary, default `repose` on PATH), PRESET (paper-scale),
# SETS (space-separated extra `--set` assignments, applied after the peer settings), RANKS (MPI
# ranks for LIGGGHTS, 1), FILL_FACTOR (insertion time allowed, × the nominal mass/rate, 2.0),
# OUT (scratch and results, default bench/liggghts-funnel/out/, git-ignored), ALSO_REPOSE=1
# (also run `repose aor` with the same spec into $OUT/repose, THREADS threads).
set -euo pipefail
HERE="$(cd "$(dirname "$0")" && pwd)"
REPOSE="${REPOSE:-repose}"
PRESET="${PRESET:-paper-scale}"
SETS="${SETS:-}"
RANKS="${RANKS:-1}"
FILL_FACTOR="${FILL_FACTOR:-2.0}"
OUT="${OUT:-$HERE/out}"
THREADS="${THREADS:-2}"

need=()
command -v liggghts >/dev/null || need+=(liggghts)
if [ "$RANKS" -gt 1 ]; then command -v mpirun >/dev/null || need+=(openmpi-bin); fi
command -v python3 >/dev/null || need+=(python3)
if [ ${#need[@]} -gt 0 ]; then
    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "${need[@]}" >/dev/null
fi
command -v "$REPOSE" >/dev/null || { echo "run.sh: no repose binary ($REPOSE); set REPOSE=" >&2; exit 2; }

# The rolling model both codes define the same way (EPSD, Ai et al. 2011) and EDEM's damping
# formula, which LIGGGHTS uses.
args=(--preset "$PRESET" --set rolling_model=epsd --set damping_law=edem_formula)
for s in $SETS; do args+=(--set "$s"); done

mkdir -p "$OUT"
"$REPOSE" aor "${args[@]}" --print-spec > "$OUT/spec.json"
"$REPOSE" aor "${args[@]}" --export-stl "$OUT"
vars="$(python3 "$HERE/spec_vars.py" "$OUT/spec.json" "$FILL_FACTOR")"
echo "$vars" > "$OUT/vars.txt"

cmd=(liggghts -in "$HERE/in.funnel" -var DIR "$OUT")
# shellcheck disable=SC2206
# Not `-screen none`: LIGGGHTS 3.8 writes mesh-reading messages to the screen unchecked and
# crashes without one.
cmd+=($vars -log "$OUT/log.liggghts" -screen "$OUT/screen.liggghts")
if [ "$RANKS" -gt 1 ]; then cmd=(mpirun --allow-run-as-root --oversubscribe -np "$RANKS" "${cmd[@]}"); fi
echo "== LIGGGHTS, $RANKS rank(s), load $(cut -d' ' -f1 /proc/loadavg), $(date -u '+%Y-%m-%d %H:%M UTC')" >&2
t0=$(date +%s)
"${cmd[@]}"
echo "   $(( $(date +%s) - t0 )) s wall" >&2
grep -a -E '^(INSERTED|ENDED)' "$OUT/log.liggghts" >&2

# The final dump as CSV (id,type,x,y,z,radius), then repose's measurement of it.
awk 'found { gsub(/ +$/, ""); gsub(/ +/, ","); print; next }
     /^ITEM: ATOMS/ { found = 1; print "id,type,x,y,z,radius" }' "$OUT/final.dump" > "$OUT/final.csv"
ligg=""
if "$REPOSE" aor "${args[@]}" --measure "$OUT/final.csv" --out "$OUT/liggghts" > "$OUT/liggghts.json"; then
    ligg="$(python3 -c 'import json,sys; print("%.2f" % json.load(open(sys.argv[1]))["angle_deg"])' "$OUT/liggghts.json")"
    echo "LIGGGHTS heap, measured by repose: ${ligg}° ($OUT/liggghts/pile.svg)"
else
    echo "LIGGGHTS heap: not measurable (above)"
fi

if [ "${ALSO_REPOSE:-0}" = 1 ]; then
    echo "== repose, $THREADS thread(s), load $(cut -d' ' -f1 /proc/loadavg)" >&2
    "$REPOSE" aor "${args[@]}" --threads "$THREADS" --quiet --out "$OUT/repose" > /dev/null || true
    python3 - "$OUT/repose/result.json" "$ligg" <<'PY'
import json, sys
r = json.load(open(sys.argv[1]))
angle = r["angle_deg"] if r["angle_deg"] is not None else r["last_angle_deg"]
text = "not measurable" if angle is None else f"{angle:.2f}°"
print(f"repose heap: {text} (status {r['status']}, ended by {r['ended_by']}, "
      f"{r['wall_time_s']:.0f} s wall, height {r['pile_height_m']}, message {r['message']})")
if angle is not None and sys.argv[2]:
    print(f"difference repose - LIGGGHTS: {angle - float(sys.argv[2]):+.2f}°")
PY
fi

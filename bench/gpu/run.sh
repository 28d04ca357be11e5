#!/usr/bin/env bash
# The GPU backend's speed figures on a machine with a GPU and no Rust toolchain, in one call
# (issue 38), most wanted first, each run alone (several GPU processes at once hung on an H200)
# and under a hard time limit, so a hung run costs its limit and not the call: the GPU crate's
# tests (TESTS), kernel profiles (PROFILE), the `paper-scale` funnel, the `fine` funnel, the
# engine benchmark at 20 k, 200 k and 2 M grains (GPU against the CPU engine on the same bed),
# the `fast` funnel's seeds on both engines, the `fast` drill and the `fast` shear test. A part
# that no longer fits BUDGET_S is skipped and says so.
#
#   REPOSE=path/to/repose BUDGET_S=560 bash bench/gpu/run.sh
#   REPOSE=path/to/repose BUDGET_S=560 GOALS=1 CHAIN=0 bash bench/gpu/run.sh       # issue 49, goal 1
#   REPOSE=path/to/repose BUDGET_S=560 GOALS=1 SLOTS_LIST= bash bench/gpu/run.sh   # issue 49, goal 2
#
# (The two goals together need about 5 + 8 minutes: two calls.) Their parts run one `repose up`
# at a time, whose one worker shares the GPU among its GPU slots in one process.
#
# REPOSE: a release build (strip it to carry it: CARGO_PROFILE_RELEASE_DEBUG=0
# CARGO_PROFILE_RELEASE_STRIP=symbols cargo build --release -p repose). TESTS: a test binary of
# the GPU crate, run first (the analytic checks on this adapter; build it with `cargo test
# --release -p repose-engine-gpu --test gpu --no-run` and strip it). PROFILE: time every kernel
# of the funnels in PROFILE_PRESETS (default `fast paper-scale fine`) for PROFILE_S seconds of
# wall time each (REPOSE_GPU_PROFILE=1; default 0, 30 s). PAPER: the paper-scale funnel
# (default 1). FINE_S: the `fine` funnel's wall-time cap (default 240; a run that reaches it
# ends cleanly and reports how far it got). BENCH: the engine benchmark (default 1). SEEDS:
# `fast` funnel seeds on the GPU (default 12); CPU_SEEDS: the same seeds on the CPU engine, all
# at once, one thread each (default 1). DRILL, SHEAR: the `fast` drill and shear test on the GPU
# (default 1). BASE: an older release build of repose; the paper-scale funnel and each
# benchmark size then also run on it, GPU only, right after the current build (a same-machine
# comparison of two builds).
# BUDGET_S: the seconds the whole script may take. Every figure is printed; the runs'
# result.json files are under $WORK (default /tmp/repose-gpu).
#
# Issue 49's goals, one GPU worker (`repose up --workers 1 --gpu-slots N`) through the job
# service; GOALS=1 runs these two parts alone (every other part off unless set):
# SLOTS_LIST (GOALS=1: "1 4 8"): for each N, SLOT_FUNNELS (8) `paper-scale` funnels on the GPU
# (one batch, the same seeds every time) on N GPU slots sharing the GPU; prints each N's wall
# time, funnels per hour and its throughput against the first N of the list (the goal: at
# least 4x one slot's). SLOT_PRESET and SLOT_SPEC (a JSON object merged over the preset) change
# the funnel (a dry run: SLOT_PRESET=fast and a small SLOT_SPEC on lavapipe). CHAIN (GOALS=1: 1):
# the paper's one-target chain at `paper-scale` on the GPU (CHAIN_CAMPAIGN, default
# examples/campaigns/paper_scale_gpu.json of this checkout) on CHAIN_SLOTS (8) GPU slots,
# stopped at CHAIN_S (480, the goal: verified within 8 minutes) or what is left of the budget;
# prints its time, stage, runs and whether it ended verified.
set -u
REPOSE=${REPOSE:-repose}
GOALS=${GOALS:-0}
# default_of WITH_GOALS OTHERWISE: a part's default with and without GOALS=1.
default_of() { if [ "$GOALS" = 1 ]; then echo "$1"; else echo "$2"; fi; }
SEEDS=${SEEDS:-$(default_of 0 12)}
CPU_SEEDS=${CPU_SEEDS:-1}
BENCH=${BENCH:-$(default_of 0 1)}
TESTS=${TESTS:-}
DRILL=${DRILL:-$(default_of 0 1)}
SHEAR=${SHEAR:-$(default_of 0 1)}
PROFILE=${PROFILE:-0}
PROFILE_S=${PROFILE_S:-30}
PROFILE_PRESETS=${PROFILE_PRESETS:-fast paper-scale fine}
PAPER=${PAPER:-$(default_of 0 1)}
FINE_S=${FINE_S:-$(default_of 0 240)}
SLOTS_LIST=${SLOTS_LIST:-$(default_of "1 4 8" "")}
SLOT_FUNNELS=${SLOT_FUNNELS:-8}
SLOT_PRESET=${SLOT_PRESET:-paper-scale}
SLOT_SPEC=${SLOT_SPEC:-"{}"}
CHAIN=${CHAIN:-$(default_of 1 0)}
CHAIN_S=${CHAIN_S:-480}
CHAIN_SLOTS=${CHAIN_SLOTS:-8}
CHAIN_CAMPAIGN=${CHAIN_CAMPAIGN:-$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)/examples/campaigns/paper_scale_gpu.json}
BASE=${BASE:-}
BUDGET_S=${BUDGET_S:-560}
WORK=${WORK:-/tmp/repose-gpu}
T0=$(date +%s)
elapsed() { echo $(( $(date +%s) - T0 )); }
stamp() { echo "== $(elapsed) s: $*"; }
# fits N WHAT: whether N more seconds fit the budget (else says WHAT is skipped).
fits() {
    if [ $(( $(elapsed) + $1 )) -le "$BUDGET_S" ]; then return 0; fi
    stamp "skipped: $2 (needs $1 s, $(( BUDGET_S - $(elapsed) )) s left)"
    return 1
}
mkdir -p "$WORK"
summary() {
    python3 - "$@" <<'PY'
import json, sys
for f in sys.argv[1:]:
    try:
        d = json.load(open(f))
    except Exception as e:
        print(f"{f}: no result ({e})")
        continue
    print(f"{f.split('/')[-2]}: {d.get('status')} angle {d.get('angle_deg')} wall {d.get('wall_time_s', 0):.1f} s "
          f"steps {d.get('steps')} simulated {d.get('simulated_time_s', 0):.2f} s {d.get('ended_by')} {d.get('engine_version')}")
PY
}
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader 2>/dev/null
lscpu | grep -E "Model name" | head -1
echo "cores: $(nproc)"
if [ -n "$TESTS" ]; then
    stamp "the GPU crate's tests on this adapter"
    REPOSE_REQUIRE_GPU=1 timeout -s KILL 120 "$TESTS" --test-threads 1 --nocapture 2>&1 |
        grep -E "^test |test result|panicked|GPU:|theory|CPU law|CPU |error" | head -80
fi
if [ -n "$SLOTS_LIST" ]; then
    # Issue 49, goal 1: the throughput of N funnels on N GPU slots of one worker.
    python3 - "$SLOT_FUNNELS" "$SLOT_PRESET" "$SLOT_SPEC" >"$WORK/funnels.json" <<'PY'
import json, sys
funnels, preset, spec = int(sys.argv[1]), sys.argv[2], json.loads(sys.argv[3])
print(json.dumps({
    "name": f"{funnels} {preset} funnels on the GPU",
    "experiment": {"kind": "aor", "backend": "gpu", "preset": preset, "spec": spec},
    "factors": [{"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.5, "high": 0.6}],
    "design": {"type": "explicit", "points": [[0.55]] * funnels},
    "response": "angle_deg", "model": "none", "seed": 49,
}))
PY
    first_rate=""
    for n in $SLOTS_LIST; do
        # One slot takes about 25 s a paper-scale funnel (BENCHMARKS: 22.9 s alone).
        need=$(( 30 + 25 * SLOT_FUNNELS / n ))
        fits "$need" "$SLOT_FUNNELS funnels on $n GPU slot(s)" || continue
        stamp "$SLOT_FUNNELS $SLOT_PRESET funnels on the GPU, one worker with $n GPU slot(s)"
        rm -f "$WORK/slots-$n.db"*
        left=$(( BUDGET_S - $(elapsed) ))
        started=$(date +%s.%N)
        timeout -k 60 -s TERM "$left" "$REPOSE" up --workers 1 --gpu-slots "$n" --listen 127.0.0.1:0 \
            --db "$WORK/slots-$n.db" --submit "$WORK/funnels.json" --exit-when-done \
            >"$WORK/slots-$n.log" 2>&1
        status=$?
        wall=$(python3 -c "print(round($(date +%s.%N) - $started, 1))")
        rate=$(python3 - "$WORK/slots-$n.db" "$n" "$wall" "$status" "$first_rate" <<'PY'
import json, sqlite3, sys
db, n, wall, status, first = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), sys.argv[4], sys.argv[5]
rows = sqlite3.connect(db).execute(
    "SELECT r.wall_time_s, r.metrics, j.state, j.attempts FROM runs r JOIN jobs j ON j.run_id = r.id"
).fetchall()
done = [r for r in rows if r[2] == "completed"]
walls = sorted(round(r[0], 1) for r in done)
angles = [round(json.loads(r[1])["angle_deg"], 2) for r in done if r[1]]
rate = len(done) * 3600 / wall
line = (f"{n} GPU slot(s): {len(done)} of {len(rows)} funnels in {wall} s (repose up exit {status}), "
        f"{rate:.0f} funnels/h; each run {walls[0] if walls else '-'}-{walls[-1] if walls else '-'} s; "
        f"runs retried {sum(r[3] > 1 for r in rows)}; angles {angles}")
if first:
    ratio = rate / float(first)
    line += f"; {ratio:.2f}x the first's throughput ({'the 4x goal met' if ratio >= 4 else 'below the 4x goal'})"
print(line, file=sys.stderr)
print(f"{rate:.6f}")
PY
)
        [ -z "$first_rate" ] && first_rate=$rate
        grep -E "GPU:|error|panicked" "$WORK/slots-$n.log" | grep -v XDG_RUNTIME_DIR | head -5
    done
fi
if [ "$CHAIN" = 1 ]; then
    # Issue 49, goal 2: the paper's one-target chain at paper-scale on one GPU worker.
    # Stopped with SIGTERM at the limit: its runs are released (up to a minute on a slow
    # device), and the database then says how far it got.
    left=$(( BUDGET_S - $(elapsed) - 60 ))
    limit=$(( left < CHAIN_S ? left : CHAIN_S ))
    if [ "$limit" -gt 60 ]; then
        stamp "the one-target chain ($(basename "$CHAIN_CAMPAIGN")), one worker with $CHAIN_SLOTS GPU slots, stopped at $limit s"
        rm -f "$WORK/chain.db"*
        started=$(date +%s.%N)
        timeout -k 60 -s TERM "$limit" "$REPOSE" up --workers 1 --gpu-slots "$CHAIN_SLOTS" \
            --listen 127.0.0.1:0 --db "$WORK/chain.db" --campaign "$CHAIN_CAMPAIGN" --exit-when-done \
            >"$WORK/chain.log" 2>&1
        status=$?
        wall=$(python3 -c "print(round($(date +%s.%N) - $started, 1))")
        grep -E "^\[|campaign|GPU:|error" "$WORK/chain.log" | grep -v XDG_RUNTIME_DIR | tail -25
        python3 - "$WORK/chain.db" "$wall" "$status" <<'PY'
import json, sqlite3, sys
db, wall, status = sys.argv[1], float(sys.argv[2]), sys.argv[3]
con = sqlite3.connect(db)
row = con.execute("SELECT status, stage, state FROM campaigns").fetchone()
if row is None:
    sys.exit(f"chain: no campaign in {db} (repose up exit {status})")
jobs = dict(con.execute("SELECT state, COUNT(*) FROM jobs GROUP BY state").fetchall())
took, count = con.execute("SELECT SUM(wall_time_s), COUNT(wall_time_s) FROM runs").fetchone()
summary = json.loads(row[2]).get("summary") or {}
verified = summary.get("within_tolerance")
print(f"chain: {row[0]} at stage {row[1]} after {wall} s (repose up exit {status}); jobs {jobs}; "
      f"{count} runs took {took or 0:.0f} s of run time; verified {verified} "
      f"(mean {summary.get('verified_mean')}, {summary.get('verified_relative_error_pct')} %); "
      f"the goal, verified within 480 s: {'met' if verified and wall <= 480 else 'not met'}")
PY
    else
        stamp "skipped: the one-target chain ($left s left)"
    fi
fi
if [ "$PROFILE" = 1 ]; then
    for preset in $PROFILE_PRESETS; do
        fits $((PROFILE_S + 15)) "the $preset profile" || continue
        stamp "$preset funnel on the GPU, every kernel timed, $PROFILE_S s of wall time"
        REPOSE_GPU_PROFILE=1 timeout -s KILL $((PROFILE_S + 60)) "$REPOSE" aor --backend gpu \
            --preset $preset --set wall_time_cap=$PROFILE_S --out "$WORK/profile-$preset" --quiet \
            2>&1 >/dev/null | grep -v XDG_RUNTIME_DIR
        summary "$WORK/profile-$preset/result.json"
    done
fi
if [ "$PAPER" = 1 ] && fits 60 "the paper-scale funnel"; then
    stamp "paper-scale funnel on the GPU, alone"
    timeout -s KILL 150 "$REPOSE" aor --backend gpu --preset paper-scale --out "$WORK/gpu-paper-scale" --quiet >/dev/null 2>&1
    summary "$WORK/gpu-paper-scale/result.json"
    if [ -n "$BASE" ] && fits 60 "the paper-scale funnel on BASE"; then
        stamp "paper-scale funnel on the GPU, BASE build, alone"
        timeout -s KILL 150 "$BASE" aor --backend gpu --preset paper-scale --out "$WORK/base-paper-scale" --quiet >/dev/null 2>&1
        summary "$WORK/base-paper-scale/result.json"
    fi
fi
cap=$(( BUDGET_S - $(elapsed) - 15 ))
cap=$(( cap < FINE_S ? cap : FINE_S ))
if [ "$cap" -gt 30 ]; then
    stamp "fine funnel on the GPU, alone, capped at $cap s of wall time"
    timeout -s KILL $((cap + 15)) "$REPOSE" aor --backend gpu --preset fine --set wall_time_cap=$cap \
        --out "$WORK/gpu-fine" --quiet >/dev/null 2>&1
    summary "$WORK/gpu-fine/result.json"
    python3 -c "import json; d = json.load(open('$WORK/gpu-fine/result.json')); print('fine:', d['grains']['inserted'], 'inserted by', d.get('insertion_end_s'), 's;', d['steps'], 'steps,', round(d['steps'] / d['wall_time_s']), 'steps/s')" 2>&1
else
    stamp "skipped: the fine funnel ($cap s left)"
fi
if [ "$BENCH" = 1 ]; then
    # bench N STEPS CPU_STEPS LIMIT: one size on this build (GPU and CPU), then on BASE (GPU).
    bench() {
        fits $(( BASE_S + $4 * 2 / 3 )) "the $1-grain benchmark" || return
        stamp "engine benchmark, $1 grains"
        timeout -s KILL "$4" "$REPOSE" bench engine --backend gpu --threads 1,"$(nproc)" \
            --particles "$1" --steps "$2" --cpu-steps "$3"
        if [ -n "$BASE" ]; then
            stamp "engine benchmark, $1 grains, BASE build, GPU only"
            timeout -s KILL "$4" "$BASE" bench engine --backend gpu --particles "$1" --steps "$2" |
                grep -E "particles|gpu"
        fi
    }
    BASE_S=0
    [ -n "$BASE" ] && BASE_S=30
    bench 20000 5000 200 60
    bench 200000 2000 40 90
    bench 2000000 500 10 150
fi
if [ "$SEEDS" -gt 0 ] && fits $(( 5 * SEEDS + 20 )) "the fast funnel's seeds"; then
    stamp "fast funnel on the GPU, seeds 1-$SEEDS, one at a time"
    for s in $(seq 1 "$SEEDS"); do
        timeout -s KILL 30 "$REPOSE" aor --backend gpu --preset fast --set seed=$s --out "$WORK/gpu-fast-$s" --quiet >/dev/null 2>&1
    done
    summary "$WORK"/gpu-fast-*/result.json
    if [ "$CPU_SEEDS" = 1 ]; then
        stamp "fast funnel on the CPU engine, seeds 1-$SEEDS, all at once, one thread each"
        for s in $(seq 1 "$SEEDS"); do
            timeout -s KILL 120 "$REPOSE" aor --preset fast --set seed=$s --threads 1 --out "$WORK/cpu-fast-$s" --quiet >/dev/null 2>&1 &
        done
        wait
        summary "$WORK"/cpu-fast-*/result.json
    fi
fi
if [ "$DRILL" = 1 ] && fits 60 "the fast drill"; then
    stamp "fast drill on the GPU (bed and drilling), alone"
    timeout -s KILL 60 "$REPOSE" drill --backend gpu --preset fast --out "$WORK/gpu-drill" --quiet >/dev/null 2>&1
    python3 -c "import json; d = json.load(open('$WORK/gpu-drill/result.json')); print({k: d.get(k) for k in ['status', 'opening_diameter_mm', 'effective_depth_mm', 'mean_feed_torque_nm', 'energy_j', 'steps', 'wall_time_s', 'engine_version']}, 'bed', d['bed']['wall_time_s'])" 2>&1
fi
if [ "$SHEAR" = 1 ] && fits 60 "the fast shear test"; then
    stamp "fast shear test on the GPU (sample and stages), alone"
    left=$(( BUDGET_S - $(elapsed) ))
    timeout -s KILL $(( left < 90 ? left : 90 )) "$REPOSE" shear --backend gpu --preset fast --out "$WORK/gpu-shear" --quiet >/dev/null 2>&1
    python3 -c "import json; d = json.load(open('$WORK/gpu-shear/result.json')); print({k: d.get(k) for k in ['status', 'cohesion_kpa', 'friction_angle_deg', 'steps', 'wall_time_s', 'engine_version']}, 'peaks', [round(s['window_peak_kpa'], 3) for s in d['stages']], 'bed', d['bed']['wall_time_s'])" 2>&1
fi
stamp "done"

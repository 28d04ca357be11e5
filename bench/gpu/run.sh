#!/usr/bin/env bash
# The GPU backend's speed figures on a machine with a GPU and no Rust toolchain, in one call
# (issue 38): the engine benchmark at 20 k, 200 k and 2 M grains (GPU against the CPU engine on
# the same bed), then the funnel on the GPU at `fast` (seeds 1-N, one process at a time: several
# GPU processes at once hung on an H200), `paper-scale` and `fine`, each alone and each under a
# hard time limit, so a hung run costs its limit and not the call.
#
#   REPOSE=path/to/repose BUDGET_S=560 bash bench/gpu/run.sh
#
# REPOSE: a release build (strip it to carry it: CARGO_PROFILE_RELEASE_DEBUG=0
# CARGO_PROFILE_RELEASE_STRIP=symbols cargo build --release -p repose). SEEDS: fast seeds
# (default 12). CPU_SEEDS: also pour the fast seeds on the CPU engine, all at once, one thread
# each (default 1). BENCH: run the engine benchmark first (default 1). TESTS: a test binary of
# the GPU crate to run first, one test at a time under a limit (the analytic checks on this
# adapter; build it with `cargo test --release -p repose-engine-gpu --test gpu --no-run` and
# strip it). DRILL: drill the `fast` bed on the GPU after the benchmark (default 1). SHEAR: the
# `fast` shear test on the GPU after that (sample and three stages; default 1). BUDGET_S:
# the seconds the whole script may take; `fine` gets what is left, as its wall-time cap (a run
# that reaches it ends cleanly and reports how far it got). PROFILE: first time every kernel of
# a `fast`, a `paper-scale` and a `fine` funnel, each for PROFILE_S seconds of wall time
# (REPOSE_GPU_PROFILE=1; default 0, 30 s). PAPER: the paper-scale funnel (default 1). Every
# figure is printed; the runs' result.json files are under $WORK (default /tmp/repose-gpu).
set -u
REPOSE=${REPOSE:-repose}
SEEDS=${SEEDS:-12}
CPU_SEEDS=${CPU_SEEDS:-1}
BENCH=${BENCH:-1}
TESTS=${TESTS:-}
DRILL=${DRILL:-1}
SHEAR=${SHEAR:-1}
PROFILE=${PROFILE:-0}
PROFILE_S=${PROFILE_S:-30}
PAPER=${PAPER:-1}
BUDGET_S=${BUDGET_S:-560}
WORK=${WORK:-/tmp/repose-gpu}
T0=$(date +%s)
elapsed() { echo $(( $(date +%s) - T0 )); }
stamp() { echo "== $(elapsed) s: $*"; }
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
if [ "$PROFILE" = 1 ]; then
    for preset in fast paper-scale fine; do
        stamp "$preset funnel on the GPU, every kernel timed, $PROFILE_S s of wall time"
        REPOSE_GPU_PROFILE=1 timeout -s KILL $((PROFILE_S + 60)) "$REPOSE" aor --backend gpu \
            --preset $preset --set wall_time_cap=$PROFILE_S --out "$WORK/profile-$preset" --quiet \
            2>&1 >/dev/null | grep -v XDG_RUNTIME_DIR
        summary "$WORK/profile-$preset/result.json"
    done
fi
if [ "$BENCH" = 1 ]; then
    B="timeout -s KILL"
    stamp "engine benchmark, 20 k"
    $B 60 "$REPOSE" bench engine --backend gpu --threads 1,$(nproc) --particles 20000 --steps 5000 --cpu-steps 200
    stamp "engine benchmark, 200 k"
    $B 90 "$REPOSE" bench engine --backend gpu --threads 1,$(nproc) --particles 200000 --steps 2000 --cpu-steps 40
    stamp "engine benchmark, 2 M"
    $B 150 "$REPOSE" bench engine --backend gpu --threads 1,$(nproc) --particles 2000000 --steps 500 --cpu-steps 10
fi
if [ "$DRILL" = 1 ]; then
    stamp "fast drill on the GPU (bed and drilling), alone"
    timeout -s KILL 60 "$REPOSE" drill --backend gpu --preset fast --out "$WORK/gpu-drill" --quiet >/dev/null 2>&1
    python3 -c "import json; d = json.load(open('$WORK/gpu-drill/result.json')); print({k: d.get(k) for k in ['status', 'opening_diameter_mm', 'effective_depth_mm', 'mean_feed_torque_nm', 'energy_j', 'steps', 'wall_time_s', 'engine_version']}, 'bed', d['bed']['wall_time_s'])" 2>&1
fi
if [ "$SHEAR" = 1 ]; then
    stamp "fast shear test on the GPU (sample and stages), alone"
    timeout -s KILL 90 "$REPOSE" shear --backend gpu --preset fast --out "$WORK/gpu-shear" --quiet >/dev/null 2>&1
    python3 -c "import json; d = json.load(open('$WORK/gpu-shear/result.json')); print({k: d.get(k) for k in ['status', 'cohesion_kpa', 'friction_angle_deg', 'steps', 'wall_time_s', 'engine_version']}, 'peaks', [round(s['window_peak_kpa'], 3) for s in d['stages']], 'bed', d['bed']['wall_time_s'])" 2>&1
fi
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
if [ "$PAPER" = 1 ]; then
    stamp "paper-scale funnel on the GPU, alone"
    timeout -s KILL 150 "$REPOSE" aor --backend gpu --preset paper-scale --out "$WORK/gpu-paper-scale" --quiet >/dev/null 2>&1
    summary "$WORK/gpu-paper-scale/result.json"
fi
left=$(( BUDGET_S - $(elapsed) - 15 ))
stamp "fine funnel on the GPU, alone, capped at $left s of wall time"
if [ "$left" -gt 30 ]; then
    timeout -s KILL $((left + 15)) "$REPOSE" aor --backend gpu --preset fine --set wall_time_cap=$left \
        --out "$WORK/gpu-fine" --quiet >/dev/null 2>&1
    summary "$WORK/gpu-fine/result.json"
    python3 -c "import json; d = json.load(open('$WORK/gpu-fine/result.json')); print('fine:', d['grains']['inserted'], 'inserted by', d.get('insertion_end_s'), 's;', d['steps'], 'steps,', round(d['steps'] / d['wall_time_s']), 'steps/s')" 2>&1
fi
stamp "done"

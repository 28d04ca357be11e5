#!/usr/bin/env bash
# Opt-in test (not part of `cargo test`): repose workers under a real Slurm.
#
# Installs Debian's slurm-wlm and munge, starts munged, a single-node slurmctld and slurmd on
# 127.0.0.1 (their own ports, state and logs in a temp directory), starts `repose server` on
# 127.0.0.1, submits repose-worker.sbatch as a job array and a small `fast` angle-of-repose
# batch, scancels the array task that is running a job mid-run, and checks that
#   - the cancelled task's worker released its job (SIGTERM), which another task then ran,
#   - the batch completes with one result per run and its analysis,
#   - the remaining array tasks end by themselves (--exit-when-idle) once the queue is empty.
# Everything it started is stopped at the end (by process id); the temp directory is kept
# for its logs unless KEEP=0.
#
# Needs root (apt-get, the daemons). Usage:
#   sudo deploy/slurm/test.sh                 # builds repose (dev profile) unless REPOSE=path
#   REPOSE=/path/to/repose sudo -E deploy/slurm/test.sh
# Knobs: TASKS (array size, default 3), IDLE_S (--exit-when-idle, default 20),
#        SLURM_PORT_BASE (default 16817: slurmctld on it, slurmd on it + 1).

set -euo pipefail

here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
repo=$(cd "$here/../.." && pwd)
tasks=${TASKS:-3}
idle_s=${IDLE_S:-20}
port_base=${SLURM_PORT_BASE:-16817}

log() { printf '[%s] %s\n' "$(date -u +%H:%M:%S)" "$*"; }
fail() {
    log "FAIL: $*"
    exit 1
}

if [[ $(id -u) -ne 0 ]]; then
    echo "test.sh: run as root: it installs packages and starts munged, slurmctld and slurmd" >&2
    exit 2
fi

work=$(mktemp -d /tmp/repose-slurm-test.XXXXXX)
chmod 0755 "$work"
started_pids=()
job_id=""
munged_started=0

cleanup() {
    local status=$?
    set +e
    if [[ -n "$job_id" ]]; then scancel "$job_id" 2>/dev/null; fi
    # Newest first: the server, slurmd, slurmctld.
    for ((i = ${#started_pids[@]} - 1; i >= 0; i--)); do
        kill "${started_pids[i]}" 2>/dev/null
        wait "${started_pids[i]}" 2>/dev/null
    done
    if [[ $munged_started -eq 1 && -s /run/munge/munged.pid ]]; then
        kill "$(cat /run/munge/munged.pid)" 2>/dev/null
    fi
    if [[ $status -ne 0 ]]; then
        log "logs in $work:"
        for f in "$work"/*.log; do
            echo "----- $f (last 15 lines)"
            tail -n 15 "$f"
        done
    elif [[ "${KEEP:-1}" == 0 ]]; then
        rm -rf "$work"
    fi
    exit $status
}
trap cleanup EXIT

log "work directory $work"

# --- packages ---------------------------------------------------------------------------------
log "apt-get install slurm-wlm munge curl jq"
apt-get update -qq
DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends \
    slurm-wlm munge curl jq >"$work/apt.log" 2>&1 || fail "apt-get install (see $work/apt.log)"
log "$(slurmctld -V), munge $(dpkg-query -W -f='${Version}' munge)"

# --- repose -----------------------------------------------------------------------------------
if [[ -z "${REPOSE:-}" ]]; then
    log "building repose (cargo build -p repose)"
    (cd "$repo" && cargo build -q -p repose)
    REPOSE="${CARGO_TARGET_DIR:-$repo/target}/debug/repose"
fi
[[ -x "$REPOSE" ]] || fail "no repose binary at $REPOSE"
"$REPOSE" worker --help | grep -q -- --exit-when-idle || fail "$REPOSE has no --exit-when-idle"
log "repose: $REPOSE ($("$REPOSE" --version))"

# --- munge ------------------------------------------------------------------------------------
install -d -o munge -g munge -m 0755 /run/munge
[[ -s /etc/munge/munge.key ]] || runuser -u munge -- mungekey --create
if ! munge -n 2>/dev/null | unmunge >/dev/null 2>&1; then
    runuser -u munge -- /usr/sbin/munged
    munged_started=1
fi
munge -n | unmunge >/dev/null || fail "munge does not work"
log "munge works"

# --- a single-node Slurm on loopback ----------------------------------------------------------
node=$(hostname -s)
cpus=$(nproc)
mkdir -p "$work/state" "$work/spool"
cat >"$work/slurm.conf" <<EOF
ClusterName=repose-test
SlurmctldHost=$node(127.0.0.1)
SlurmctldPort=$port_base
SlurmdPort=$((port_base + 1))
SlurmUser=root
AuthType=auth/munge
StateSaveLocation=$work/state
SlurmdSpoolDir=$work/spool
SlurmctldPidFile=$work/slurmctld.pid
SlurmdPidFile=$work/slurmd.pid
SlurmctldLogFile=$work/slurmctld.log
SlurmdLogFile=$work/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
MpiDefault=none
ReturnToService=2
KillWait=30
NodeName=$node NodeAddr=127.0.0.1 CPUs=$cpus State=UNKNOWN
PartitionName=test Nodes=$node Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$work/slurm.conf"
slurmctld -D -c >"$work/slurmctld.out.log" 2>&1 &
started_pids+=($!)
slurmd -D >"$work/slurmd.out.log" 2>&1 &
started_pids+=($!)
for _ in $(seq 60); do
    state=$(sinfo -h -n "$node" -o %t 2>/dev/null || true)
    [[ "$state" == idle ]] && break
    sleep 1
done
[[ "$state" == idle ]] || fail "the Slurm node did not become idle (state '$state')"
log "Slurm up: node $node, $cpus CPUs, partition test"

# --- repose server ----------------------------------------------------------------------------
db="$work/repose.db"
user_token=$("$REPOSE" token create tester --db "$db" 2>/dev/null)
"$REPOSE" token create slurm-workers --role worker --db "$db" 2>/dev/null >"$work/worker-token"
chmod 0600 "$work/worker-token"
"$REPOSE" server --listen 127.0.0.1:0 --db "$db" --lease-s 20 \
    >"$work/server.out" 2>"$work/server.log" &
started_pids+=($!)
for _ in $(seq 100); do
    url=$(sed -n 's/^listening on //p' "$work/server.out" 2>/dev/null | head -n 1)
    [[ -n "$url" ]] && break
    sleep 0.1
done
[[ -n "$url" ]] || fail "repose server did not start"
log "repose server at $url"
api() { curl -sf -H "Authorization: Bearer $user_token" "$url$1"; }

# --- the job array and a batch ----------------------------------------------------------------
job_id=$(cd "$work" && REPOSE_SERVER="$url" REPOSE_WORKER_TOKEN_FILE="$work/worker-token" \
    REPOSE_BIN="$REPOSE" REPOSE_EXIT_WHEN_IDLE="$idle_s" \
    sbatch --parsable --array="1-$tasks" --cpus-per-task=1 --time=30 \
    --output="$work/worker-%A_%a.log" "$here/repose-worker.sbatch")
log "submitted job array $job_id (tasks 1-$tasks, 1 CPU each, --exit-when-idle $idle_s)"

cat >"$work/batch.json" <<'EOF'
{
  "name": "slurm test: fast AOR",
  "experiment": {"kind": "aor", "preset": "fast", "spec": {"total_mass": 0.025}},
  "factors": [
    {"name": "mu_s", "path": "soil_soil.static_friction", "low": 0.4, "high": 0.6},
    {"name": "mu_r", "path": "soil_soil.rolling_friction", "low": 0.2, "high": 0.4}
  ],
  "design": {"type": "factorial"},
  "response": "angle_deg",
  "model": "linear",
  "seed": 5
}
EOF
batch=$(REPOSE_SERVER="$url" REPOSE_TOKEN="$user_token" "$REPOSE" submit "$work/batch.json" |
    awk '{print $1}')
log "submitted batch $batch: $(api "/v1/batches/$batch" | jq -c '{runs: .counts}')"

# --- scancel the array task that runs a job, mid-job ------------------------------------------
victim=""
for _ in $(seq 600); do
    victim=$(api /v1/workers | jq -r '[.[] | select(.running_jobs > 0) | .host][0] // empty')
    [[ -n "$victim" ]] && break
    sleep 0.2
done
[[ -n "$victim" ]] || fail "no worker ever ran a job"
task=${victim##*_}
sleep 1 # well inside the run (a fast AOR run takes several seconds)
log "worker $victim is running a job; scancel ${job_id}_$task"
scancel "${job_id}_$task"

# --- the batch completes ----------------------------------------------------------------------
deadline=$((SECONDS + 900))
while :; do
    status=$(api "/v1/batches/$batch")
    [[ $(jq -r .state <<<"$status") != active ]] && break
    ((SECONDS < deadline)) || fail "batch not finished in 15 min: $status"
    sleep 2
done
log "batch finished: $(jq -c '{state, counts}' <<<"$status")"
[[ $(jq -r .state <<<"$status") == completed ]] || fail "batch state is not completed"
[[ $(jq -r .counts.completed <<<"$status") == 4 ]] || fail "not 4 completed runs"

victim_log="$work/worker-${job_id}_$task.log"
plain() { sed 's/\x1b\[[0-9;]*m//g' "$1"; }
for _ in $(seq 30); do plain "$victim_log" | grep -q "released at shutdown" && break; sleep 1; done
released=$(plain "$victim_log" | sed -n 's/.*job released at shutdown job=\([0-9a-f-]*\).*/\1/p' | head -n 1)
[[ -n "$released" ]] || fail "the cancelled task did not release its job"
log "cancelled task's log: $(plain "$victim_log" | grep -o 'job released at shutdown.*' | head -n 1)"
releases=$(api /metrics | awk '$1 == "repose_releases_total" {print $2}')
((releases >= 1)) || fail "the server counted no release"
workers=$(api /v1/workers)
hosts() { jq -r --argjson workers "$workers" \
    '($workers | map({(.id): .host}) | add) as $h | .[] | "  run \(.run_index): \(.status), attempts \(.attempts), angle_deg \(.metrics.angle_deg // "-"), by \($h[.worker_id])"'; }
api "/v1/batches/$batch/runs" | hosts
finisher=$(api "/v1/jobs?batch=$batch" | jq -r --arg id "$released" '.[] | select(.id == $id) | .worker_id')
finisher_host=$(jq -r --arg id "$finisher" '.[] | select(.id == $id) | .host' <<<"$workers")
[[ -n "$finisher_host" && "$finisher_host" != "$victim" ]] ||
    fail "the released job $released was not finished by another worker (by '$finisher_host')"
log "the released job $released was finished by $finisher_host"
analysis=$(api "/v1/batches/$batch/analysis")
[[ $(jq -r .runs_used <<<"$analysis") -ge 3 ]] || fail "analysis used fewer than 3 runs: $analysis"
log "analysis stored (runs used: $(jq -r .runs_used <<<"$analysis"))"

# --- the other array tasks end by themselves once the queue stays empty -----------------------
for _ in $(seq $((idle_s * 3 + 60))); do
    [[ -z $(squeue -h -j "$job_id" 2>/dev/null) ]] && break
    sleep 1
done
[[ -z $(squeue -h -j "$job_id" 2>/dev/null) ]] || fail "array tasks still queued or running: $(squeue -j "$job_id")"
idle_exits=$(grep -l "no job for the idle limit" "$work"/worker-"${job_id}"_*.log | wc -l)
((idle_exits >= 1)) || fail "no array task exited by --exit-when-idle"
log "every array task ended; $idle_exits by --exit-when-idle, task $task by scancel"
log "PASS"

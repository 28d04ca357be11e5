//! Wire types of the repose job server, shared by the server, the workers and the command line.
//!
//! Everything here is plain data plus pure helpers (no I/O), so a worker can depend on this
//! crate without pulling in the server's database or HTTP stack.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use serde_json::Value;
use uuid::Uuid;

pub mod spec_path;
pub mod version;

pub use spec_path::{apply_factor_values, locate_mut, PathMode, SpecPathError};
pub use version::{check_worker_version, ReleaseVersion, VersionRefusal};

/// The OpenAPI 3.0 document of the server's HTTP API (`api/openapi.json`, served at
/// `GET /openapi.json`). Hand-written; the server's tests compare it with its route table and
/// with real responses.
pub const OPENAPI_JSON: &str = include_str!("../openapi.json");

// ---------------------------------------------------------------------------------------------
// Submissions
// ---------------------------------------------------------------------------------------------

/// A calibration batch: one experiment template, the factors to vary and the design to run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BatchRequest {
    /// Human-readable label, e.g. `"sand AOR screening"`.
    pub name: String,
    /// The simulation every run starts from.
    pub experiment: ExperimentTemplate,
    /// Parameters to vary, each bound to a dotted path in `experiment.spec`.
    pub factors: Vec<FactorSpec>,
    /// Which runs to simulate.
    pub design: DesignRequest,
    /// Copies of every design point, each with its own seed (default 1).
    #[serde(default = "default_replicates")]
    pub replicates: u32,
    /// Metric reported by the workers that the model is fitted to, e.g. `"angle_deg"`.
    pub response: String,
    /// Regression model fitted when the batch finishes.
    pub model: ModelName,
    /// Desired response value; when set, the analysis searches for the settings that hit it.
    #[serde(default)]
    pub target: Option<f64>,
    /// Base seed for run order and per-run seeds; chosen by the server when absent.
    #[serde(default)]
    pub seed: Option<u64>,
    /// Store the runs' pictures (SVG, ~50-200 KB each) on the server, e.g. for a campaign
    /// report; off by default because a large batch would fill the database with them.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub keep_pictures: bool,
}

fn default_replicates() -> u32 {
    1
}

/// Which engine runs an experiment, as a spec, a job or a command line names it (serde `cpu`,
/// `gpu`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BackendKind {
    /// The CPU engine: the reference, deterministic for any thread count.
    #[default]
    Cpu,
    /// The GPU engine (`repose-engine-gpu`): deterministic per adapter, f32.
    Gpu,
}

impl BackendKind {
    /// `cpu` or `gpu` (the serde, database and command-line name).
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Gpu => "gpu",
        }
    }

    /// `CPU` or `GPU`, for messages.
    pub fn label(self) -> &'static str {
        match self {
            BackendKind::Cpu => "CPU",
            BackendKind::Gpu => "GPU",
        }
    }

    /// The CPU engine (the default, which a template leaves out when it serialises).
    pub fn is_cpu(&self) -> bool {
        *self == BackendKind::Cpu
    }
}

impl std::fmt::Display for BackendKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The experiment every run of a batch is a variation of.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExperimentTemplate {
    /// Experiment type understood by the workers: `aor`, `drill`, `shear`, and the test aids
    /// `table_lookup` and `formula`.
    pub kind: String,
    /// The engine the runs need: `cpu` or `gpu` (`aor`, `drill` and `shear` run on it); none:
    /// the CPU in a batch, the campaign's `backend` in a campaign (so an explicit `cpu` is
    /// told from none). GPU jobs go only to workers that opened a GPU adapter
    /// (`repose worker --gpu`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backend: Option<BackendKind>,
    /// Named starting point for the spec (e.g. `fast` or `default` for `aor`); `spec` is merged
    /// over it, so it need only give what differs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub preset: Option<String>,
    /// The experiment's own document (or the part that differs from the preset); factor values
    /// are written into the completed spec at their paths.
    #[serde(default = "empty_object")]
    pub spec: Value,
}

impl ExperimentTemplate {
    /// The engine the runs need: the template's own, else the CPU.
    pub fn backend(&self) -> BackendKind {
        self.backend.unwrap_or_default()
    }
}

fn empty_object() -> Value {
    Value::Object(serde_json::Map::new())
}

/// One varied parameter and its natural range.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FactorSpec {
    /// Factor name used in the design, the model terms and the reports.
    pub name: String,
    /// Dotted path into the experiment spec, e.g. `material.friction` or `particles.0.radius`.
    /// Absent: a column of the design that is not written into the spec (a campaign's factor
    /// that acts on another of its experiments keeps the batches' design rows aligned).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
    /// Natural value at coded -1.
    pub low: f64,
    /// Natural value at coded +1.
    pub high: f64,
}

impl FactorSpec {
    /// The `(path, value)` pairs a run writes into its spec: each factor with a path, with its
    /// natural value (factors and values in factor order).
    pub fn assignments<'a>(
        factors: &'a [FactorSpec],
        natural: &'a [f64],
    ) -> impl Iterator<Item = (&'a str, f64)> + 'a {
        factors
            .iter()
            .zip(natural)
            .filter_map(|(f, &v)| Some((f.path.as_deref()?, v)))
    }
}

/// How to choose the design points.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum DesignRequest {
    /// Two-level full factorial (2^k runs).
    Factorial,
    /// Plackett–Burman screening design; `runs` defaults to the smallest size that fits.
    PlackettBurman {
        /// 8, 12, 16, 20 or 24.
        #[serde(default)]
        runs: Option<usize>,
    },
    /// Box–Behnken design; `centre_points` defaults to the textbook count for k factors.
    BoxBehnken {
        /// Centre-point runs appended after the edge runs.
        #[serde(default)]
        centre_points: Option<usize>,
    },
    /// Central composite design.
    CentralComposite {
        /// Where the star points sit.
        variant: CcdVariantName,
        /// Centre-point runs appended at the end.
        centre_points: usize,
    },
    /// Points given by the user, in natural units, one value per factor in factor order.
    Explicit {
        /// Rows of natural factor values.
        points: Vec<Vec<f64>>,
    },
}

/// Placement of a central composite design's star points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CcdVariantName {
    /// Rotatable, star points outside the ranges.
    Circumscribed,
    /// Star points on the cube faces.
    FaceCentred,
    /// Rotatable, shrunk so the star points sit at the range limits.
    Inscribed,
}

/// Regression model families.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ModelName {
    /// Intercept and main effects.
    #[serde(rename = "linear")]
    Linear,
    /// Main effects and two-factor interactions.
    #[serde(rename = "2fi")]
    TwoFactorInteraction,
    /// Full second-order model.
    #[serde(rename = "quadratic")]
    Quadratic,
    /// No regression: the analysis summarises the response (mean, standard deviation, …), for
    /// replicate runs at one point such as a verification batch.
    #[serde(rename = "none")]
    None,
}

/// Reply to a successful submission.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchCreated {
    /// The new batch.
    pub id: Uuid,
    /// Number of runs (design points × replicates), one job each.
    pub run_count: usize,
}

// ---------------------------------------------------------------------------------------------
// Progress views
// ---------------------------------------------------------------------------------------------

/// Life cycle of a batch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BatchState {
    /// Runs remain queued or running.
    Active,
    /// Every run finished (completed or dead); the analysis is available.
    Completed,
    /// Cancelled by a user; unfinished runs will not be executed.
    Cancelled,
}

/// Life cycle of one run (one job).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RunState {
    /// Waiting for a worker (possibly after a retry back-off).
    Queued,
    /// Leased by a worker.
    Running,
    /// A result is stored.
    Completed,
    /// Failed `max_attempts` times; will not be retried.
    Dead,
    /// Its batch was cancelled before it finished.
    Cancelled,
}

impl RunState {
    /// The spelling used in JSON, CSV and the database.
    pub fn as_str(self) -> &'static str {
        match self {
            RunState::Queued => "queued",
            RunState::Running => "running",
            RunState::Completed => "completed",
            RunState::Dead => "dead",
            RunState::Cancelled => "cancelled",
        }
    }
}

/// Number of runs in each state.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct StateCounts {
    /// Waiting for a worker.
    pub queued: u64,
    /// Leased by a worker.
    pub running: u64,
    /// Result stored.
    pub completed: u64,
    /// Gave up after too many failures.
    pub dead: u64,
    /// Cancelled with the batch.
    pub cancelled: u64,
}

impl StateCounts {
    /// All runs of the batch.
    pub fn total(&self) -> u64 {
        self.queued + self.running + self.completed + self.dead + self.cancelled
    }

    /// Runs that will not change any more.
    pub fn finished(&self) -> u64 {
        self.completed + self.dead + self.cancelled
    }
}

/// One line of the batch list.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchSummary {
    /// Batch id.
    pub id: Uuid,
    /// Label given at submission.
    pub name: String,
    /// Experiment type.
    pub kind: String,
    /// Life cycle state.
    pub state: BatchState,
    /// Submission time, Unix milliseconds.
    pub created_at_ms: i64,
    /// Runs per state.
    pub counts: StateCounts,
    /// Finished runs as a percentage of all runs.
    pub percent_done: f64,
    /// Name of the user token that submitted the batch (only it may cancel the batch);
    /// `None` for batches submitted before the server had access control.
    #[serde(default)]
    pub owner: Option<String>,
    /// The engine its runs need (`experiment.backend`).
    #[serde(default)]
    pub backend: BackendKind,
    /// Set while the batch's GPU jobs wait for a GPU worker and none was seen lately.
    #[serde(default)]
    pub gpu_wait: Option<GpuWait>,
}

/// Jobs that need a GPU and no worker with one to run them: no worker that registered a GPU
/// adapter was seen (registered, claimed or heartbeated) within the last `minutes`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct GpuWait {
    /// The window looked at, minutes.
    pub minutes: u32,
}

impl std::fmt::Display for GpuWait {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "waiting for a GPU worker: none registered in the last {} min",
            self.minutes
        )
    }
}

/// Detailed progress of one batch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchStatus {
    /// Identity, state and counts.
    #[serde(flatten)]
    pub summary: BatchSummary,
    /// Response the model is fitted to.
    pub response: String,
    /// Model fitted at the end.
    pub model: ModelName,
    /// Mean wall time of the completed runs, seconds.
    pub mean_wall_time_s: Option<f64>,
    /// Estimated seconds until the last run finishes: mean wall time × remaining runs / runs in
    /// flight (at least one). `None` until a run has completed or when nothing remains.
    pub eta_s: Option<f64>,
    /// Whether `GET /v1/batches/{id}/analysis` has a result.
    pub analysis_ready: bool,
}

/// Value of one factor in one run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FactorValue {
    /// Factor name.
    pub name: String,
    /// Coded value (-1 … +1 for the cube).
    pub coded: f64,
    /// Natural value written into the spec.
    pub natural: f64,
}

/// One run with its settings and, once finished, its result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunView {
    /// Run id.
    pub id: Uuid,
    /// Position in the (randomised) run order.
    pub run_index: u32,
    /// Row of the design this run simulates.
    pub design_row: u32,
    /// Replicate number, from 0.
    pub replicate: u32,
    /// Factor settings in factor order.
    pub factors: Vec<FactorValue>,
    /// DEM random seed.
    pub seed: u64,
    /// Life cycle state.
    pub status: RunState,
    /// Leases handed out so far (released leases are not counted).
    pub attempts: u32,
    /// Reported metrics, once completed.
    pub metrics: Option<BTreeMap<String, f64>>,
    /// Wall time of the successful attempt, seconds.
    pub wall_time_s: Option<f64>,
    /// Worker that produced the result (or holds the lease).
    pub worker_id: Option<Uuid>,
    /// Last failure message.
    pub last_error: Option<String>,
    /// First 16 hex digits of the SHA-256 of the exact spec sent to the workers: equal
    /// hashes simulated the same document.
    #[serde(default)]
    pub spec_sha256: Option<String>,
    /// Engine version that computed the result (from the worker's completion).
    #[serde(default)]
    pub engine_version: Option<String>,
}

/// One worker as listed by `GET /v1/workers`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorkerView {
    /// Instance id chosen by the worker.
    pub id: Uuid,
    /// Host name it reported.
    pub host: String,
    /// Threads per simulation.
    pub threads: u32,
    /// Worker software version.
    pub version: String,
    /// The GPU adapter it opened (its GPU slots claim `gpu` jobs); none: CPU jobs only.
    #[serde(default)]
    pub gpu: Option<String>,
    /// The GPU's memory, bytes, as the worker reported it (none: not known).
    #[serde(default)]
    pub gpu_memory_bytes: Option<u64>,
    /// Runs it shares its GPU among at once (`repose worker --gpu-slots`).
    #[serde(default)]
    pub gpu_slots: Option<u32>,
    /// Jobs of `gpu` batches it holds a lease on now (runs in flight on its GPU).
    #[serde(default)]
    pub gpu_running_jobs: u64,
    /// First registration, Unix milliseconds.
    pub registered_at_ms: i64,
    /// Last registration, claim or heartbeat, Unix milliseconds.
    pub last_seen_at_ms: i64,
    /// Jobs it holds a lease on now.
    pub running_jobs: u64,
}

/// One job (the queue entry of a run) as listed by `GET /v1/jobs`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobView {
    /// Job id (used in the worker protocol paths).
    pub id: Uuid,
    /// The run it computes.
    pub run_id: Uuid,
    /// The run's batch.
    pub batch_id: Uuid,
    /// Position of the run in its batch's run order.
    pub run_index: u32,
    /// Life cycle state (`running` = leased).
    pub status: RunState,
    /// Leases used so far.
    pub attempts: u32,
    /// Worker holding the current lease.
    pub worker_id: Option<Uuid>,
    /// Last reported progress of the current lease, 0..1.
    pub progress: Option<f64>,
    /// When the current lease expires, Unix milliseconds.
    pub lease_expires_at_ms: Option<i64>,
    /// Earliest time a queued job may be claimed (retry back-off), Unix milliseconds.
    pub available_at_ms: i64,
    /// Last failure message.
    pub last_error: Option<String>,
    /// Last change, Unix milliseconds.
    pub updated_at_ms: i64,
}

// ---------------------------------------------------------------------------------------------
// Worker protocol
// ---------------------------------------------------------------------------------------------

/// A worker introduces itself when it starts; registering again with the same `instance_id`
/// updates the record. Because a registration means the worker has (re)started, any job still
/// leased to that `instance_id` is not running any more and goes back to the queue at once.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorkerRegistration {
    /// Chosen by the worker at start-up; identifies it in claims and run records. A worker that
    /// keeps its id across restarts (`repose up`'s local workers, `repose worker --instance-id`)
    /// gets the jobs it held back in the queue when it comes back, instead of after their lease.
    pub instance_id: Uuid,
    /// Host name, for people reading the run table.
    pub host: String,
    /// Threads the worker runs each simulation with.
    pub threads: u32,
    /// Worker software version (its release, `MAJOR.MINOR.PATCH`); the server accepts only
    /// its own `MAJOR.MINOR` (see [`version`]).
    pub version: String,
    /// The GPU adapter the worker opened (`repose worker --gpu`): only workers that name one
    /// claim jobs of `gpu` batches. None: it runs CPU jobs only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gpu: Option<String>,
    /// The GPU's memory, bytes, where the worker knows it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gpu_memory_bytes: Option<u64>,
    /// Runs the worker shares its GPU among at once (its GPU slots).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub gpu_slots: Option<u32>,
}

/// Reply to a registration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorkerRegistered {
    /// Id to send in claims (equal to the instance id).
    pub worker_id: Uuid,
    /// Lease length the server grants; heartbeat well within it.
    pub lease_s: f64,
}

/// Ask for a job, waiting up to `wait_s` seconds (at most 30) for one to appear.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClaimRequest {
    /// Registered worker id.
    pub worker_id: Uuid,
    /// Long-poll duration; 0 answers at once.
    #[serde(default)]
    pub wait_s: f64,
    /// The engine of the slot asking: `gpu` leases only jobs of `gpu` batches (a worker that
    /// registered a GPU adapter), `cpu` only CPU jobs; none: any job the worker can run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub backend: Option<BackendKind>,
}

/// A leased job: everything a worker needs to run one simulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClaimResponse {
    /// Job id, used in the heartbeat/complete/fail/release paths.
    pub job_id: Uuid,
    /// Proves ownership of the lease; send it with every update.
    pub lease_token: Uuid,
    /// Seconds until the lease expires unless renewed by a heartbeat.
    pub lease_expires_in_s: f64,
    /// The run this job computes.
    pub run_id: Uuid,
    /// The run's batch.
    pub batch_id: Uuid,
    /// Experiment type.
    pub kind: String,
    /// The engine the run needs (the batch's `experiment.backend`).
    #[serde(default)]
    pub backend: BackendKind,
    /// Experiment spec with this run's factor values written at their paths.
    pub spec: Value,
    /// DEM random seed of this run.
    pub seed: u64,
    /// Which lease this is for the job (1 for the first).
    pub attempt: u32,
    /// The batch keeps pictures: send them with the completion.
    #[serde(default)]
    pub keep_pictures: bool,
}

/// Periodic proof of life; renews the lease.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Heartbeat {
    /// Token from the claim.
    pub lease_token: Uuid,
    /// Fraction done, 0..1.
    #[serde(default)]
    pub progress: f64,
}

/// Reply to a heartbeat.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HeartbeatResponse {
    /// Stop working: the batch was cancelled or the run already has a result.
    pub cancel: bool,
    /// Seconds until the renewed lease expires.
    pub lease_expires_in_s: f64,
}

/// A finished simulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Completion {
    /// Token from the claim.
    pub lease_token: Uuid,
    /// Scalar results, e.g. `angle_deg`; must include the batch's response.
    pub metrics: BTreeMap<String, f64>,
    /// Time the simulation took, seconds.
    pub wall_time_s: f64,
    /// Anything else worth keeping (fit residuals, file names, …).
    #[serde(default)]
    pub details: Value,
    /// Version of the DEM engine that computed the result, for provenance.
    #[serde(default)]
    pub engine_version: Option<String>,
    /// Pictures by file name (SVG text); stored only if the batch keeps pictures.
    #[serde(default)]
    pub pictures: BTreeMap<String, String>,
}

/// A simulation that could not produce a result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Failure {
    /// Token from the claim.
    pub lease_token: Uuid,
    /// What went wrong, for the run table.
    pub error: String,
    /// Rerunning cannot help (the experiment is deterministic for its spec and seed, e.g. the
    /// heap never settled): the run is marked dead at once instead of retried.
    #[serde(default)]
    pub permanent: bool,
    /// Rerunning with this seed cannot help, but another seed may (e.g. grains arched over
    /// the funnel's outlet in this pour): the server gives the run a new seed and queues it at
    /// once, while it has attempts left; the run keeps the seed that gave its result. Not
    /// together with `permanent`.
    #[serde(default)]
    pub another_seed: bool,
}

/// Give a job back without it counting as an attempt (e.g. the worker is shutting down).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Release {
    /// Token from the claim.
    pub lease_token: Uuid,
}

/// What happened to a job update.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct JobUpdateResponse {
    /// The run's state after the update.
    pub status: RunState,
}

// ---------------------------------------------------------------------------------------------
// Campaigns (the request type lives in `repose-campaign`, which owns its validation)
// ---------------------------------------------------------------------------------------------

/// Reply to `POST /v1/campaigns`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignCreated {
    /// The new campaign.
    pub id: Uuid,
    /// Its first (screening) batch, already queued.
    pub first_batch: Uuid,
}

/// One line of `GET /v1/campaigns`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignSummary {
    /// Campaign id.
    pub id: Uuid,
    /// Label given at submission.
    pub name: String,
    /// `running`, `finished` or `needs_attention`.
    pub status: String,
    /// Stage of the outstanding (or last) batch: `screening`, `steepest`, …
    pub stage: String,
    /// Batches issued so far.
    pub batches: u64,
    /// Submission time, Unix milliseconds.
    pub created_at_ms: i64,
    /// Last change, Unix milliseconds.
    pub updated_at_ms: i64,
    /// Set while one of its batches waits for a GPU worker and none was seen lately.
    #[serde(default)]
    pub gpu_wait: Option<GpuWait>,
}

/// A batch a campaign issued, with its progress.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignBatch {
    /// Issue order, from 0.
    pub index: u64,
    /// Stage it belongs to.
    pub stage: String,
    /// The batch (`GET /v1/batches/{id}` for details).
    pub batch_id: Uuid,
    /// Its life-cycle state.
    pub state: BatchState,
    /// Finished runs as a percentage of all its runs.
    pub percent_done: f64,
}

/// A decision the campaign took and why.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignDecision {
    /// Stage that decided.
    pub stage: String,
    /// Response-surface round.
    pub round: u32,
    /// The explanation, in plain words.
    pub text: String,
}

/// `GET /v1/campaigns/{id}`: where a campaign is and what it decided so far.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CampaignView {
    /// Identity, status and stage.
    #[serde(flatten)]
    pub summary: CampaignSummary,
    /// Why it stopped, when `status` is `needs_attention`.
    pub reason: Option<String>,
    /// Progress of the outstanding batch, percent.
    pub stage_percent_done: Option<f64>,
    /// Batches in issue order.
    pub batch_list: Vec<CampaignBatch>,
    /// Decisions in order.
    pub decisions: Vec<CampaignDecision>,
    /// The calibrated parameters and verification, once finished.
    pub result: Option<Value>,
}

// ---------------------------------------------------------------------------------------------
// Analysis and errors
// ---------------------------------------------------------------------------------------------

/// Statistical analysis of a finished batch, computed once and stored.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AnalysisView {
    /// Batch analysed.
    pub batch_id: Uuid,
    /// Computation time, Unix milliseconds.
    pub computed_at_ms: i64,
    /// Response fitted.
    pub response: String,
    /// Model fitted.
    pub model: ModelName,
    /// Factor names in model order.
    pub factors: Vec<String>,
    /// Completed runs used in the fit.
    pub runs_used: usize,
    /// The fit (coefficients, ANOVA, fit statistics, diagnostics) as produced by `repose-doe`.
    pub fit: Option<Value>,
    /// Settings predicted to hit the target (only when the batch has a target).
    pub optimum: Option<Value>,
    /// Steepest-ascent (or descent, towards the target) path; linear models only. Beside the
    /// path's own fields: its `direction` and the model's `predicted` response at each point.
    pub steepest_path: Option<Value>,
    /// Summary of the response over the completed runs: `n`, `mean`, `std`, `min`, `max`, and
    /// with a target the `target` and (unless it is 0) the `relative_error_pct` of the mean.
    #[serde(default)]
    pub summary: Option<Value>,
    /// Why the fit or a later step could not be computed.
    pub error: Option<String>,
}

/// Body of every error reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ApiError {
    /// Human-readable explanation.
    pub error: String,
    /// The offending request field, as a dotted path (e.g. `factors[1].low`), when one is to blame.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub field: Option<String>,
}

/// Liveness reply of `GET /healthz`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Health {
    /// Always `"ok"` when the server answers and its database responds.
    pub status: String,
    /// Server version.
    pub version: String,
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn batch_request_defaults_and_design_tags() {
        let request: BatchRequest = serde_json::from_value(json!({
            "name": "b",
            "experiment": {"kind": "aor", "spec": {"mu": 0.5}},
            "factors": [{"name": "mu", "path": "mu", "low": 0.2, "high": 0.8}],
            "design": {"type": "box_behnken"},
            "response": "angle_deg",
            "model": "2fi"
        }))
        .unwrap();
        assert_eq!(request.replicates, 1);
        assert_eq!(request.model, ModelName::TwoFactorInteraction);
        assert_eq!(
            request.design,
            DesignRequest::BoxBehnken {
                centre_points: None
            }
        );
        let ccd: DesignRequest = serde_json::from_value(json!({
            "type": "central_composite", "variant": "face_centred", "centre_points": 3
        }))
        .unwrap();
        assert_eq!(
            ccd,
            DesignRequest::CentralComposite {
                variant: CcdVariantName::FaceCentred,
                centre_points: 3
            }
        );
    }

    #[test]
    fn a_template_runs_on_the_cpu_unless_it_names_the_gpu() {
        let none: ExperimentTemplate = serde_json::from_value(json!({"kind": "aor"})).unwrap();
        assert_eq!((none.backend, none.backend()), (None, BackendKind::Cpu));
        let cpu: ExperimentTemplate =
            serde_json::from_value(json!({"kind": "aor", "backend": "cpu"})).unwrap();
        assert_eq!(cpu.backend, Some(BackendKind::Cpu));
        assert_eq!(serde_json::to_value(&cpu).unwrap()["backend"], "cpu");
        // A template without one serialises as before the field existed (stored requests
        // unchanged); one that names the CPU keeps saying so.
        assert_eq!(
            serde_json::to_value(&none).unwrap(),
            json!({"kind": "aor", "spec": {}})
        );
        let gpu: ExperimentTemplate =
            serde_json::from_value(json!({"kind": "aor", "backend": "gpu"})).unwrap();
        assert_eq!(gpu.backend(), BackendKind::Gpu);
        assert_eq!(serde_json::to_value(&gpu).unwrap()["backend"], "gpu");
        let err =
            serde_json::from_value::<ExperimentTemplate>(json!({"kind": "aor", "backend": "tpu"}))
                .unwrap_err();
        assert!(err.to_string().contains("unknown variant `tpu`"), "{err}");
    }

    #[test]
    fn unknown_design_is_rejected() {
        let err = serde_json::from_value::<DesignRequest>(json!({"type": "latin_square"}));
        assert!(err.is_err());
    }

    #[test]
    fn api_error_omits_missing_field() {
        let body = serde_json::to_string(&ApiError {
            error: "x".into(),
            field: None,
        })
        .unwrap();
        assert_eq!(body, r#"{"error":"x"}"#);
    }
}

//! Calibration campaigns: screening → steepest ascent/descent → response surface → optimum →
//! verification (→ optional drilling validation), as pure decisions over finished batches, and
//! the campaign report. No I/O, no HTTP, no SQL: the server persists a [`Campaign`] as JSON,
//! submits the batches it returns and calls [`Campaign::advance`] when each one finishes.
//!
//! # How a server drives a campaign
//!
//! 1. `POST /v1/campaigns` → parse a [`CampaignRequest`] and call [`Campaign::start`]; it
//!    validates the request (errors name the field) and returns the state plus the screening
//!    [`repose_api::BatchRequest`]. Submit it, remember that server batch id ↔ campaign batch
//!    index `0` ([`Campaign::outstanding`]), store the campaign JSON.
//! 2. When a batch of the campaign finishes, build a [`StageResult`] (`batch` = the campaign's
//!    index, `runs` = the batch's runs, optionally its analysis) and call
//!    [`Campaign::advance`]. It returns [`Next::Submit`] (submit and store again),
//!    [`Next::Finished`] or [`Next::NeedsAttention`]. The state is updated in place; store it
//!    after every call. After a restart, load the JSON and carry on — the state holds
//!    everything the next decision needs.
//! 3. Keep every batch's runs: [`report_json`] and [`report_html`] take all of them
//!    (`&[StageResult]`, any order) and recompute the fits for the tables and figures.
//!
//! # Stages and the rules they follow
//!
//! 1. **Screening** (`<name>: screening`): all candidates over their `[low, high]`,
//!    Plackett–Burman by default (or a factorial, or explicit points in natural units), linear
//!    model. Significant = ANOVA p < α. More than `screening.max_factors` (3) significant → the
//!    largest |t| are kept; none significant → the `screening.fallback_factors` (2) largest |t|
//!    are carried and the decision says the screening could not separate them from noise. The
//!    others are held at `fixed_at` or mid-range, written into every later batch's spec.
//! 2. **Steepest path** (`<name>: steepest path`): Montgomery's path over the carried factors
//!    from the screening coefficients (the paper's Eqs. 13-15): the base factor (largest
//!    |coefficient|) moves one half-range per step, the others `b_i/|b_base|` of their
//!    half-range, rounded to `steepest.round_decimals`. Start at a corner (default, the paper) or
//!    the centre; with `direction: auto` from a corner, the corner whose prediction lies on the
//!    near side of the target is chosen (ascent from the low corner when both work and it is
//!    nearer). Points are clamped to the allowed ranges and the path ends where every factor
//!    sits at its bound or at `max_points`. `points_per_dispatch` points are sent per batch;
//!    the stage stops when two consecutive responses bracket the target (or one is within
//!    tolerance), else the next points are sent. The point closest to the target up to the first
//!    crossing is the centre (points beyond it were only run because several are dispatched at
//!    once; a point within tolerance wins outright).
//!    Never crossing → the closest point is used anyway and the decision says so.
//! 3. **Response surface** (`<name>: response surface`): Box–Behnken (5 centre points) by
//!    default or a CCD, centred on that point with half-ranges = the path steps (at least 5 % of
//!    the allowed half-range), clamped to the allowed ranges; 2 factors → face-centred CCD,
//!    1 factor → a five-level line. Full quadratic model and ANOVA.
//! 4. **Optimum**: Derringer–Suich desirability for the target (as `repose analyze
//!    --target`), the whole level set reported (starts at desirability 1, distinct settings,
//!    spread, per-factor extent); the chosen setting is the tied one nearest the design centre.
//! 5. **Verification** (`<name>: verification`): an explicit one-point batch at the optimum,
//!    `verification.replicates` (3) replicates, model `none`, fresh seeds. Accepted if the mean
//!    is within `tolerance` (`{"relative_pct": 5}` by default, or `{"absolute": x}`). If not,
//!    a further response-surface round centred at the optimum: with half the half-ranges when
//!    the target was reachable in the last region, with the same half-ranges (the region moves)
//!    when it was not; at most
//!    `response_surface.max_extra_rounds` (2) times; then [`Next::NeedsAttention`].
//! 6. **Drilling validation** (optional `drilling`, also spelled `validation`;
//!    `<name>: drilling validation`): one explicit batch of the validation experiment (the
//!    drilling test; it is not a target) at the calibrated parameters (paths remapped by
//!    `drilling.paths`), each measured metric compared with the simulated mean. A failure is
//!    reported in the decisions and the summary; the calibration itself is still finished.
//!
//! With `seed` set, batch `i` gets the seed `splitmix64(seed ^ i·φ)`, so every batch —
//! verification included — has fresh simulation seeds; without it the server chooses.
//!
//! # Several targets
//!
//! With `targets` (each `<experiment>.<metric>`, a measured value and a tolerance) and
//! `experiments` (templates by name), the plan is simultaneous, by Derringer–Suich
//! desirability: every stage issues one batch per experiment the targets need, with the same
//! design, one after the other (each is an ordinary outstanding batch; the finished ones wait in
//! [`Campaign::pending`]) and decides when the last has finished. Screening fits one linear
//! model per response (a factor is significant if it is for any response, ranked by its largest
//! |t|); the path climbs the overall desirability (its gradient under the screening models at
//! the screening centre; centred on its most desirable point once it peaked, or on the most
//! desirable point with every response in tolerance as soon as there is one); the response surface fits one quadratic per
//! response; the optimum maximises the overall desirability; verification accepts only if
//! every response is within its own tolerance. The one-target form behaves exactly as before.
//!
//! # The Bayesian strategy
//!
//! With `"strategy": {"type": "bayesian", "max_runs": 60, "batch_size": 4}` (the default is
//! `{"type": "doe"}`, the chain above) the campaign varies every candidate factor at once over
//! its whole range, with no stages and no significance gate (`screening`, `steepest`,
//! `response_surface` and `stage_experiments` are refused):
//!
//! 1. **Start** (`<name>: space-filling start`): a maximin Latin hypercube of
//!    `initial_points` (default `2·factors + 2`), one explicit batch per experiment the targets
//!    need, all issued at once ([`Campaign::begin`] returns them all; [`Campaign::step`] takes
//!    each finished one and answers [`Step::Wait`] until the round is complete).
//! 2. **Surrogates**: one Gaussian process per response over the factors written into its own
//!    experiment only (anisotropic squared-exponential kernel with estimated noise, inputs
//!    normalised to `[0, 1]`, outputs standardised; the `friedrich` crate; no length-scale
//!    shorter than two sides of the cell each distinct setting stands for, `2·m^(-1/d)`), and
//!    one on feasibility (+1 where every run gave its metrics, −1 where one failed) when a run
//!    failed.
//! 3. **Assessment**: over a few thousand candidates (a Latin hypercube and perturbations of the
//!    best points), the probability that the mean of `verification.replicates` runs of every
//!    target lands within its tolerance, times the probability of feasibility.
//! 4. **Verify** (`<name>: verification N`) at the best candidate when that probability reaches
//!    `stop_probability` (0.8); a failed verification's runs join the data and the search goes
//!    on. Else **stop** when the targets conflict (each reachable alone with probability ≥ 0.5,
//!    together below `conflict_probability`, two rounds running; the reason names the
//!    responses), when a target is out of reach even alone (below 0.5 everywhere, two rounds
//!    running, and no run met it within two noise standard deviations at an edge of the box: a
//!    target met so is named "met only at the edge of the factor box" with the factor and the
//!    edge, and never stops the campaign), or when `max_runs` leaves no room (with room for the
//!    verification only, the best point is verified). Else **propose** (`<name>: search round
//!    N`) `batch_size` points by kriging believer and go to 2; the last one explores (the highest
//!    probability at a mean moved up to two posterior standard deviations toward the targets):
//!    for each target out of reach or met only at an edge, one aimed at it alone, else, with
//!    two points or more, one for all targets.
//! 5. The drilling validation, when asked for, runs at the verified point as in the chain.
//!
//! The result ([`Summary`]) adds `simulations` and `bayesian` ([`BayesianResult`]: the region
//! of settings consistent with every measurement, each response's factor influences (the
//! total-effect share of each factor in the variation of its surrogate's mean; none for a
//! factor not written into its experiment), the convergence, the Pareto front of the
//! per-target misfits, the failed points and the targets met only at an edge). A campaign
//! that ends without a verification still carries its best observed point there, with
//! `within_tolerance: false`. All draws come from `seed` and the round, and the state holds
//! every observation, so a campaign resumed from its stored JSON decides as an uninterrupted
//! one.
mod campaign;
mod error;
mod report;
mod request;

pub use campaign::{
    Assessment, BayesState, BayesVerification, BayesianResult, CalibratedValue, Campaign,
    CarryRule, ConvergencePoint, Decision, DrillMetric, DrillingOutcome, Edge, EdgeReach,
    HeldFactor, InfeasiblePoint, Influence, IssuedBatch, LevelSetPoint, Next, Observation,
    OptimumChoice, ParetoPoint, PathPoint, PathState, Region, ResponseCheck, ResponseEffects,
    ScreeningOutcome, StageKind, StageResult, Status, Step, Summary, SurfaceFitSummary,
    SurfaceRound, VerificationOutcome,
};
pub use error::CampaignError;
pub use report::{report_html, report_json, ReportPictures};
pub use request::{
    relative_error_pct, BayesianSettings, CampaignRequest, CandidateFactor, DrillingValidation,
    PathDirectionSetting, PathStartSetting, ScreeningSettings, StageExperiments, StageTemplate,
    SteepestSettings, Strategy, SurfaceDesign, SurfaceSettings, Target, TargetSetting, Tolerance,
    VerificationSettings,
};

//! The Bayesian strategy's sentences: every decision and stop of `bayes` in plain words.

use super::{Assessment, BayesStop, BayesVerification, EdgeReach, OutOfReach, Proposal};
use crate::campaign::wording::setting;
use crate::campaign::{fmt_num, Summary};
use crate::request::{BayesianSettings, Target};

fn pct(p: f64) -> String {
    if p >= 0.001 {
        format!("{} %", fmt_num(100.0 * p))
    } else {
        "< 0.1 %".to_owned()
    }
}

/// The plan at the start.
pub(crate) fn start(
    points: usize,
    factors: usize,
    experiments: usize,
    settings: &BayesianSettings,
) -> String {
    format!(
        "Bayesian strategy: all {factors} candidate factors at once over their whole ranges. \
         Space-filling start: a maximin Latin hypercube of {points} points{}. Then rounds of up \
         to {} points where every target is most likely met under one Gaussian-process \
         surrogate per response, until the best point's probability reaches {}; at most {} \
         simulations in all, verification included.",
        if experiments > 1 {
            format!(", each run by all {experiments} experiments")
        } else {
            String::new()
        },
        settings.batch_size,
        pct(settings.stop_probability),
        settings.max_runs
    )
}

/// A response has too few values for a surrogate.
pub(crate) fn too_few_values(response: &str, points: usize) -> String {
    format!(
        "Too few completed runs of {response} to fit its surrogate: {points} more space-filling \
         points."
    )
}

/// A run that completed without a target's metric.
pub(crate) fn missing_metric(metric: &str) -> String {
    format!("the run completed without a finite `{metric}`")
}

/// What the surrogates say after a round.
pub(crate) fn assessment(a: &Assessment, targets: &[Target], names: &[String]) -> String {
    let each: Vec<String> = targets
        .iter()
        .zip(&a.alone)
        .map(|(t, p)| format!("{} {}", t.label, pct(*p)))
        .collect();
    let predicted: Vec<String> = targets
        .iter()
        .zip(&a.predicted)
        .map(|(t, v)| format!("{} {}", t.label, fmt_num(*v)))
        .collect();
    let mut text = format!(
        "The surrogates' best point ({}) meets every target with probability {} (predicted {}).",
        setting(names, &a.best),
        pct(a.probability),
        predicted.join(", ")
    );
    if targets.len() > 1 {
        text.push_str(&format!(
            " Best probability of each target alone: {}.",
            each.join(", ")
        ));
    }
    if !a.out_of_reach.is_empty() {
        text.push_str(&format!(
            " Out of reach even alone: {}.",
            a.out_of_reach.join(", ")
        ));
    }
    if !a.at_edge.is_empty() {
        text.push(' ');
        text.push_str(&at_edges(&a.at_edge));
    }
    if !a.conflicts.is_empty() {
        text.push_str(&format!(
            " Each is reachable, not together: {}.",
            a.conflicts
                .iter()
                .map(|(x, y)| format!("{x} with {y}"))
                .collect::<Vec<_>>()
                .join("; ")
        ));
    }
    text
}

/// The next round's points.
pub(crate) fn proposal(p: &Proposal, names: &[String]) -> String {
    let list = |points: &[&Vec<f64>]| {
        points
            .iter()
            .map(|p| format!("({})", setting(names, p)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let total = p.exploit.len() + p.explore.len();
    let mut parts = Vec::new();
    if !p.exploit.is_empty() {
        let exploit: Vec<&Vec<f64>> = p.exploit.iter().collect();
        parts.push(format!(
            "{} where every target is most likely met, by kriging believer: {}",
            exploit.len(),
            list(&exploit)
        ));
    }
    for (aims, point) in &p.explore {
        parts.push(if aims.is_empty() {
            format!(
                "1 exploring where the surrogates know least, at the highest probability within \
                 two standard deviations of their means: {}",
                list(&[point])
            )
        } else {
            format!(
                "1 exploring where {} could still be met, at its highest probability within two \
                 standard deviations of its surrogate's mean: {}",
                aims.join(" and "),
                list(&[point])
            )
        });
    }
    format!("Next round: {total} point(s), {}.", parts.join("; "))
}

/// A target met only at the edge of the factor box: the edges, and the runs that met it.
pub(crate) fn at_edge(e: &EdgeReach) -> String {
    let edges: Vec<String> = e
        .edges
        .iter()
        .map(|x| {
            format!(
                "{} at its {} edge ({})",
                x.factor,
                if x.high { "high" } else { "low" },
                fmt_num(x.value)
            )
        })
        .collect();
    format!(
        "{} ({}; {} run(s) within its band or two noise standard deviations ({} each) of it, \
         the closest {})",
        e.response,
        edges.join(", "),
        e.runs,
        fmt_num(e.noise_sd),
        fmt_num(e.closest)
    )
}

/// The sentence for the targets met only at the edge of the factor box.
fn at_edges(reaches: &[EdgeReach]) -> String {
    format!(
        "Met only at the edge of the factor box, not out of reach: {}; a wider range beyond \
         that edge may hold it.",
        reaches.iter().map(at_edge).collect::<Vec<_>>().join("; ")
    )
}

/// A verification is issued.
pub(crate) fn verify(
    point: &[f64],
    names: &[String],
    probability: f64,
    replicates: u32,
    last_chance: bool,
) -> String {
    if last_chance {
        format!(
            "The budget leaves room for the verification only: {replicates} replicate(s) at the \
             best point ({}), whose probability of meeting every target is {}.",
            setting(names, point),
            pct(probability)
        )
    } else {
        format!(
            "Verification: {replicates} replicate(s) at ({}), which meets every target with \
             probability {}.",
            setting(names, point),
            pct(probability)
        )
    }
}

/// A verification's outcome.
pub(crate) fn verification(v: &BayesVerification) -> String {
    let checks: Vec<String> = v
        .checks
        .iter()
        .map(|c| {
            format!(
                "{} mean {} against {} ({} %{})",
                c.response,
                fmt_num(c.mean),
                fmt_num(c.target),
                fmt_num(c.relative_error_pct),
                if c.within_tolerance { "" } else { ", outside" }
            )
        })
        .collect();
    let failed = if v.failed_runs > 0 {
        format!(" {} replicate(s) failed.", v.failed_runs)
    } else {
        String::new()
    };
    if v.within_tolerance {
        format!("Verified: {}.", checks.join("; "))
    } else {
        format!(
            "Verification failed: {}.{failed} Its runs join the data and the search goes on.",
            checks.join("; ")
        )
    }
}

/// Why a Bayesian campaign stopped without a verified calibration.
pub(crate) fn stop(stop: &BayesStop, summary: &Summary, names: &[String]) -> String {
    let values: Vec<f64> = summary.parameters.iter().map(|p| p.value).collect();
    let observed = if summary.targets.is_empty() {
        format!("observed mean {}", fmt_num(summary.verified_mean))
    } else {
        summary
            .targets
            .iter()
            .map(|c| format!("{} {}", c.response, fmt_num(c.mean)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    let edges = match summary.bayesian.as_deref() {
        Some(b) if !b.at_edge.is_empty() => format!(" {}", at_edges(&b.at_edge)),
        _ => String::new(),
    };
    let reason = match stop {
        BayesStop::Conflict { pairs } => format!(
            "the targets cannot be met together in the factor box: {}. Each is reachable alone \
             under the surrogates, together they are not. Best compromise observed: ({}) with \
             {observed}; the Pareto front of the per-target misfits is in the result.",
            pairs
                .iter()
                .map(|(a, b)| format!("{a} conflicts with {b}"))
                .collect::<Vec<_>>()
                .join("; "),
            setting(names, &values)
        ),
        BayesStop::OutOfReach { targets } => format!(
            "{} in the factor box, even alone: {}. Widen the factors' ranges, add a factor, or \
             check the measurement. Closest compromise observed: ({}) with {observed}.",
            if targets.len() == 1 {
                "a target cannot be reached"
            } else {
                "targets cannot be reached"
            },
            targets
                .iter()
                .map(out_of_reach)
                .collect::<Vec<_>>()
                .join("; "),
            setting(names, &values)
        ),
        BayesStop::BudgetSpent { simulations } => format!(
            "the budget of simulations is spent ({simulations} issued) without a verified \
             calibration. Best point observed: ({}) with {observed}.",
            setting(names, &values)
        ),
        BayesStop::NothingCompleted => "no run of the start design gave the targets' metrics \
                                        and the budget leaves no room for more: check the \
                                        experiments and the factor ranges"
            .to_owned(),
    };
    reason + &edges
}

/// One target out of reach: where its band lies against what was observed.
fn out_of_reach(t: &OutOfReach) -> String {
    let (lo, hi) = (
        t.band.target - t.band.half_width,
        t.band.target + t.band.half_width,
    );
    let observed = match t.observed {
        Some((min, max)) => format!("observed {} to {}", fmt_num(min), fmt_num(max)),
        None => "nothing observed".to_owned(),
    };
    format!(
        "{} (band {} to {}; {observed}; the surrogates give it at most {} anywhere)",
        t.label,
        fmt_num(lo),
        fmt_num(hi),
        pct(t.alone)
    )
}

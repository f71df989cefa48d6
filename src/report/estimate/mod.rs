//! `estimate`'s and `simulate`'s output: an estimate of Q and R from recorded measurements
//! (maximum likelihood with standard errors and its convergence, autocovariance least
//! squares, a full Q or R) as a table or JSON, where a tune's start came from, and what
//! `simulate` wrote.

use std::fmt::Write;
use std::path::Path;

use crate::estimate::als::AlsEstimate;
use crate::estimate::ml::{self, MlEstimate};
use crate::params::ParamSpace;
use crate::report::format::fmt_g;

#[cfg(feature = "sdp")]
mod full;
mod ranges;
#[cfg(feature = "sdp")]
pub use full::{full_json, full_text};
pub use ranges::{ranges_json, ranges_text, rests_on};

/// What every estimate's summary names: the problem, the record and its size, the
/// parameters and where the search started.
#[derive(Debug, Clone, Copy)]
pub struct EstimateSummary<'a> {
    /// The problem's name.
    pub problem: &'a str,
    /// The record of measurements, as given.
    pub record: &'a Path,
    /// Sequences in the record.
    pub sequences: usize,
    /// Steps in the record, every sequence's.
    pub steps: usize,
    /// Measured values in the record (empty cells not counted).
    pub values: usize,
    /// The problem's parameters.
    pub params: &'a ParamSpace,
    /// The start values, one per parameter.
    pub start: &'a [f64],
    /// Seconds the estimate took.
    pub seconds: f64,
    /// The L-BFGS iteration limit (maximum likelihood).
    pub max_iterations: u64,
}

/// An estimate as the JSON `--json` prints: the problem, the method, the parameter names,
/// the estimate and its time. `extra` adds fields (a full matrix's names).
pub fn estimate_json(
    summary: &EstimateSummary<'_>,
    method: &str,
    estimate: &impl serde::Serialize,
    extra: serde_json::Map<String, serde_json::Value>,
) -> String {
    let mut value = serde_json::json!({
        "problem": summary.problem,
        "method": method,
    });
    let map = value.as_object_mut().expect("an object");
    map.extend(extra);
    map.insert("params".into(), serde_json::json!(summary.params.names()));
    map.insert(
        "estimate".into(),
        serde_json::to_value(estimate).expect("serializes"),
    );
    map.insert("seconds".into(), serde_json::json!(summary.seconds));
    let mut text = serde_json::to_string_pretty(&value).expect("serializes");
    text.push('\n');
    text
}

/// The autocovariance least-squares estimate as a table: each parameter's estimate, the
/// unconstrained least-squares value and the start, the fit's residual, and the parameters
/// the constraint held at zero.
pub fn als_text(summary: &EstimateSummary<'_>, est: &AlsEstimate) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "autotune estimate: {} from {} ({} sequence(s), {} innovations), autocovariance least squares, lags 0..{}",
        summary.problem,
        summary.record.display(),
        summary.sequences,
        est.samples,
        est.lags - 1
    );
    let _ = writeln!(
        o,
        "{:<14} {:>12} {:>14} {:>12}  unit",
        "parameter", "estimate", "unconstrained", "start"
    );
    for (i, d) in summary.params.params.iter().enumerate() {
        let unc = if d.fixed {
            "fixed".to_string()
        } else {
            fmt_g(est.unconstrained[i])
        };
        let _ = writeln!(
            o,
            "{:<14} {:>12} {:>14} {:>12}  {}",
            d.name,
            fmt_g(est.theta[i]),
            unc,
            fmt_g(summary.start[i]),
            d.unit
        );
    }
    let _ = writeln!(
        o,
        "rms residual of the autocovariances {}; filter at the start: spectral radius of F(I − KH) {:.4}; {:.3} s",
        fmt_g(est.residual),
        est.spectral_radius,
        summary.seconds
    );
    if !est.at_zero.is_empty() {
        let names: Vec<&str> = est
            .at_zero
            .iter()
            .map(|&i| summary.params.params[i].name.as_str())
            .collect();
        let _ = writeln!(
            o,
            "held at zero by the constraint (unconstrained least squares would make them negative): {}",
            names.join(", ")
        );
    }
    o
}

/// The maximum-likelihood estimate as a table: each parameter's estimate, standard error
/// and start, the likelihood at the start and at the estimate, the search's cost, whether
/// it converged (and if not, why), and the parameters at their bound or not identified.
pub fn ml_text(summary: &EstimateSummary<'_>, est: &MlEstimate) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "autotune estimate: {} from {} ({} sequence(s), {} values), maximum likelihood",
        summary.problem,
        summary.record.display(),
        summary.sequences,
        summary.values
    );
    let _ = writeln!(
        o,
        "{:<14} {:>12} {:>12} {:>12}  unit",
        "parameter", "estimate", "std error", "start"
    );
    for (i, d) in summary.params.params.iter().enumerate() {
        let se = match (d.fixed, est.std_errors[i]) {
            (true, _) => "fixed".to_string(),
            (false, Some(s)) => fmt_g(s),
            (false, None) if est.at_bound.contains(&i) => "at bound (0)".to_string(),
            (false, None) => "not identified".to_string(),
        };
        let _ = writeln!(
            o,
            "{:<14} {:>12} {:>12} {:>12}  {}",
            d.name,
            fmt_g(est.theta[i]),
            se,
            fmt_g(summary.start[i]),
            d.unit
        );
    }
    let _ = writeln!(
        o,
        "−log L: {} at the start, {} at the estimate; {} L-BFGS iterations ({} restart(s)), {} Newton step(s), {} likelihood evaluations, {:.3} s",
        fmt_g(est.start_neg_log_likelihood),
        fmt_g(est.neg_log_likelihood),
        est.iterations,
        est.restarts,
        est.newton_steps,
        est.evaluations,
        summary.seconds,
    );
    convergence_line(&mut o, summary, est);
    if !est.at_bound.is_empty() {
        let names: Vec<&str> = est
            .at_bound
            .iter()
            .map(|&i| summary.params.params[i].name.as_str())
            .collect();
        let _ = writeln!(
            o,
            "at the bound (0): {} (setting it to zero changes −log L by less than 0.001 nats); the other standard errors leave it out",
            names.join(", ")
        );
    }
    if !est.not_identified.is_empty() {
        let names: Vec<&str> = est
            .not_identified
            .iter()
            .map(|&i| summary.params.params[i].name.as_str())
            .collect();
        let _ = writeln!(
            o,
            "not identified by these data (relative standard error above 1, or no curvature): {}",
            names.join(", ")
        );
    }
    o
}

/// Whether the likelihood's maximum was reached: the gain the quadratic model still
/// predicts and the gradient, or why not (parameters stuck near zero, gain left, no
/// maximum) and whether the iteration limit stopped it.
fn convergence_line(o: &mut String, summary: &EstimateSummary<'_>, est: &MlEstimate) {
    let gradient: Vec<String> = est.gradient.iter().map(|g| fmt_g(*g)).collect();
    if est.converged {
        let _ = writeln!(
            o,
            "converged: the quadratic model at the estimate predicts {} nats still to gain (below {}); gradient in log θ [{}]",
            fmt_g(est.predicted_improvement),
            fmt_g(ml::PREDICTED_TOL),
            gradient.join(", ")
        );
    } else {
        let names = |ix: &[usize]| -> String {
            ix.iter()
                .map(|&i| summary.params.params[i].name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let why = if !est.stuck.is_empty() {
            format!(
                "{} stayed near zero although the likelihood pulls them up",
                names(&est.stuck)
            )
        } else if est.predicted_improvement.is_finite() {
            format!(
                "the quadratic model at the estimate predicts {} nats still to gain",
                fmt_g(est.predicted_improvement)
            )
        } else {
            "the information at the estimate is not positive definite (not a maximum)".to_string()
        };
        let _ = writeln!(
            o,
            "not converged: {why}; gradient in log θ [{}]{}",
            gradient.join(", "),
            if est.iterations >= summary.max_iterations {
                " (iteration limit reached: raise --max-iterations)"
            } else {
                ""
            }
        );
    }
}

/// Where a tune's search starts: `start: ml estimate from FILE in 0.123 s: q = …, r = …`.
pub fn start_note(
    method: &str,
    origin: &str,
    seconds: f64,
    params: &ParamSpace,
    theta: &[f64],
) -> String {
    let shown: Vec<String> = params
        .params
        .iter()
        .zip(theta)
        .map(|(d, v)| format!("{} = {}", d.name, fmt_g(*v)))
        .collect();
    format!(
        "start: {method} estimate from {origin} in {seconds:.3} s: {}",
        shown.join(", ")
    )
}

/// What `simulate` wrote.
pub fn simulate_text(
    runs: usize,
    steps: usize,
    components: usize,
    out: &Path,
    seed: u64,
) -> String {
    format!(
        "wrote {runs} run(s) × {steps} steps of {components} measurement components to {} (seed {seed})\n",
        out.display()
    )
}

/// The names of a full-matrix estimate's process noise inputs: each after its Q term's
/// parameter, with an index when the term has more than one input.
#[cfg(feature = "sdp")]
fn input_names(
    summary: &EstimateSummary<'_>,
    est: &crate::estimate::als_full::FullEstimate,
    model: &crate::estimate::als::AlsModel<'_>,
) -> Vec<String> {
    use crate::params::Coef;
    // Each noise input is named after its Q term's parameter (with an index when the term
    // has more than one input).
    est.input_terms
        .iter()
        .enumerate()
        .map(|(j, &ti)| {
            let base = match model.q.terms[ti].coef {
                Coef::Param(i) => summary.params.params[i].name.clone(),
                Coef::Fixed(_) => format!("fixed term {}", ti + 1),
            };
            let of_term: Vec<usize> = (0..est.input_terms.len())
                .filter(|&k| est.input_terms[k] == ti)
                .collect();
            if of_term.len() > 1 {
                let pos = of_term.iter().position(|&k| k == j).unwrap_or(0);
                format!("{base}[{pos}]")
            } else {
                base
            }
        })
        .collect()
}

//! Why no Q and R fit: causes as fitted hypotheses, compared on what they achieve (issue 38).
//!
//! A tuning run that ends [`TuneStatus::Inconsistent`] has shown, with its certificate
//! ([`crate::tune::certify`]), that no value of the free parameters makes the filter
//! consistent; it has not shown why. Each candidate cause is a change of the filter's model
//! with its own parameters, fitted by the same search as the noise parameters (a trial):
//! - for a linear problem, every [`Hypothesis`] (the time step with F *and* Q rebuilt, the
//!   initial covariance, a sensor's gain or its measurement matrix, a delay, coloured
//!   sensor noise, a sensor bias, a missing motion state, the noise model's kind, a full
//!   R), through [`Hypothesized`];
//! - a fixed parameter freed;
//! - a search bound widened (the tuner's own widening, or the certificate's box).
//!
//! The explanations are ranked by what their trial achieved: a change that makes the filter
//! consistent comes first — with the fewest added parameters, then the best score — and when several fit, the data do not decide between them and the result says
//! so. A trial whose change ends at its neutral value (a time scale of 1, a gain of 1, …)
//! changed nothing: it is no evidence for its cause. Changes that were tried and did not
//! fit come next, then what could not be tried (never above a tried one); no cause is named
//! by default. When none fits, the result says that, lists what was tried and shows the
//! evidence (which components, which way) without naming a cause.

use crate::experiment::{Experiment, Hypothesis};
use crate::montecarlo::McConfig;
use crate::tune::{TuneError, TuneResult, TuneSettings, TuneStatus};

mod explanation;
mod remedy;
#[cfg(test)]
mod tests;
mod trials;

use explanation::slow_correlation;
pub use explanation::{Cause, Explanation, Trial};

/// Mark the fits that are cases of a simpler hypothesis that fits too: coloured sensor noise
/// whose every fitted correlation outlasts the run (a per-step correlation above
/// `1 − 1/steps`) is a bias; a measurement matrix where the gains alone fit is a gain.
fn mark_nested(out: &mut [Explanation], steps: usize) {
    let fits = |out: &[Explanation], h: Hypothesis| {
        out.iter()
            .any(|e| e.cause == Cause::Model(h) && e.trial.as_ref().is_some_and(Trial::fits))
    };
    let all = |t: &Trial, prefix: &str, keep: &dyn Fn(f64) -> bool| {
        let v: Vec<f64> = t
            .values
            .iter()
            .filter(|(n, _)| n.starts_with(prefix))
            .map(|(_, v)| *v)
            .collect();
        !v.is_empty() && v.iter().all(|&x| keep(x))
    };
    let bias = fits(out, Hypothesis::SensorBias);
    let gain = fits(out, Hypothesis::SensorGain);
    let slow = slow_correlation(steps);
    for e in out.iter_mut() {
        let Some(t) = e.trial.as_mut() else { continue };
        if !t.fits() {
            continue;
        }
        t.same_as = match e.cause {
            Cause::Model(Hypothesis::ColouredNoise)
                if bias && all(t, "gm_corr_", &|c| c >= slow) =>
            {
                Some(Hypothesis::SensorBias)
            }
            // The gains are the measurement matrix without its rotations: where they fit,
            // the rotations are not needed.
            Cause::Model(Hypothesis::MeasurementMatrix) if gain => Some(Hypothesis::SensorGain),
            _ => None,
        };
    }
}

/// Whether a tuning run needs explaining: its tuned filter failed the confirmation, or it
/// had to widen a search bound to find one that passes.
pub fn needed(result: &TuneResult) -> bool {
    matches!(
        result.status,
        TuneStatus::Inconsistent | TuneStatus::Undecided
    ) || !result.widened.is_empty()
}

/// The explanations of `result` (a run of [`crate::tune::tune`] on `experiment` under `mc`
/// and `settings`), ranked as the module says. Empty when the run needs no explaining
/// ([`needed`]).
pub fn explain(
    experiment: &dyn Experiment,
    result: &TuneResult,
    mc: &McConfig,
    settings: &TuneSettings,
) -> Result<Vec<Explanation>, TuneError> {
    if !needed(result) {
        return Ok(Vec::new());
    }
    let mut out = trials::bounds(experiment, result);
    if result.status == TuneStatus::Consistent {
        return Ok(out);
    }
    // A failure the recheck on more runs did not repeat is no misfit to explain: a change
    // that fits would be no evidence for a cause.
    if result
        .certificate
        .as_ref()
        .is_some_and(|c| c.recheck_passed == Some(true))
    {
        return Ok(out);
    }
    let t = trials::Trials {
        experiment,
        result,
        mc,
        settings,
    };
    out.extend(t.free_fixed()?);
    out.extend(t.hypotheses()?);
    mark_nested(&mut out, mc.steps());
    order(&mut out);
    Ok(out)
}

/// Order explanations as the module says: fits first (the fewest added parameters, then the
/// best score), then tried, then untried; stable within a rank, so the trials' order stays.
fn order(out: &mut [Explanation]) {
    out.sort_by(|a, b| {
        a.rank()
            .cmp(&b.rank())
            .then_with(|| match (&a.trial, &b.trial) {
                (Some(x), Some(y)) if a.rank() == 0 => {
                    a.added.cmp(&b.added).then(x.score.total_cmp(&y.score))
                }
                _ => std::cmp::Ordering::Equal,
            })
    });
}

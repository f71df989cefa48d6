//! The trials: each candidate change fitted by the same search as the noise parameters.

use super::explanation::{Cause, Explanation, Trial, slow_correlation};
use super::remedy::{fmt_value, read, with_unit};
use crate::experiment::{Changed, Experiment, Hypothesis, Hypothesized, ReadThrough, Rebounded};
use crate::montecarlo::McConfig;
use crate::tune::certify::WIDEN;
use crate::tune::{LocalSearch, Scoring, Silent, TuneError, TuneResult, TuneSettings, tune};

/// The bounds the tuner widened: the widening was the trial.
pub(super) fn bounds(experiment: &dyn Experiment, result: &TuneResult) -> Vec<Explanation> {
    let params = &experiment.params().params;
    result
        .widened
        .iter()
        .map(|w| {
            let p = &params[w.param];
            let side = if w.to.0 < w.from.0 { "lower" } else { "upper" };
            let still = result.at_bound.get(w.param).copied().unwrap_or(false);
            let t = Trial {
                change: format!(
                    "widening its {side} bound once, to [{}, {}]",
                    fmt_value(w.to.0),
                    fmt_value(w.to.1)
                ),
                status: result.status,
                passed: result.confirmation.passed,
                seeds: result.confirmation.seeds,
                band_low: result.confirmation.band_low,
                values: vec![(p.name.clone(), result.tuned[w.param])],
                evaluations: 0,
                score: result.objective_final.total,
                neutral: false,
                nis_only: false,
                recorded: result.confirmation.recorded,
                same_as: None,
            };
            let remedy = if still {
                format!(
                    "{} is at its bound even after widening: the data want it further still",
                    p.name
                )
            } else {
                format!(
                    "widen {}'s bounds in the problem file (the fit is {})",
                    p.name,
                    with_unit(result.tuned[w.param], &p.unit)
                )
            };
            Explanation {
                cause: Cause::SearchBounds,
                subject: p.name.clone(),
                evidence: format!(
                    "{} stopped at its {side} bound {} of [{}, {}]",
                    p.name,
                    fmt_value(if side == "lower" { w.from.0 } else { w.from.1 }),
                    fmt_value(w.from.0),
                    fmt_value(w.from.1)
                ),
                remedy,
                trial: Some(t),
                untried: None,
                added: 0,
            }
        })
        .collect()
}

/// The score below which a trial's search has found a fit and stops: its statistics then
/// sit within a few percent of their targets, and the confirmation judges the rest.
const TRIAL_FIT: f64 = 1e-5;

/// The evaluations of a trial's first look.
const LOOK_EVALS: usize = 300;

/// The evaluations of a first look per free parameter, where that gives more.
const LOOK_PER_PARAM: usize = 50;

/// How far below the unchanged filter's best score a first look must come for the change
/// to be searched in full.
const LOOK_GAIN: f64 = 0.7;

/// The evaluations a trial's search may spend.
const TRIAL_EVALS: usize = 1500;

/// The trials' shared settings: every trial is a [`tune`] of the changed experiment from
/// the run's best fit, with the run's own settings and Monte Carlo test.
pub(super) struct Trials<'a> {
    pub(super) experiment: &'a dyn Experiment,
    pub(super) result: &'a TuneResult,
    pub(super) mc: &'a McConfig,
    pub(super) settings: &'a TuneSettings,
}

impl Trials<'_> {
    /// The settings of a trial: the run's (its NIS-only scoring included), with its
    /// confirmation seed, no certification of its own, the first moments weighed, and the
    /// simplex (unless the user chose a local search).
    pub(super) fn settings_for(&self) -> TuneSettings {
        // A trial's question is whether a consistent filter exists with the change, which
        // its confirmation answers; a few hundred evaluations find the fit where one exists.
        let evals = self.settings.max_evals().min(TRIAL_EVALS);
        // The first moments weigh in: the gate's zero-mean tests judge what a structural
        // change gets wrong by a little (a step 2% off leaves a mean error proportional to
        // the velocity, which a larger Q hides from the second moments: measured, a time
        // step fit to J = 0 without it passing 7 of 12 seeds).
        let mut weights = self.settings.weights();
        if weights.bias == 0.0 {
            weights.bias = 1.0;
        }
        let s = self
            .settings
            .clone()
            .with_weights(weights)
            .expect("weights with one more > 0")
            .with_max_evals(evals)
            .expect("a budget of at least one evaluation")
            .with_stop_below(TRIAL_FIT)
            // No scan of the box: the trial starts where the evidence is (the best fit, the
            // designer's values) with the change at its neutral value, which a scan of a box
            // of a dozen dimensions only leads away from.
            .with_from_estimate(true)
            .with_certify(false)
            .with_confirm_seed(Some(self.result.confirm_seed));
        // The simplex: a change's own parameters have no components of their own for the
        // moment equations, and Levenberg–Marquardt from a best fit that moved the noise
        // parameters to make up for the change stays in that basin (measured: a sensor gain
        // of 1.32 fit from the designer's values by the simplex, not by it).
        if self.settings.local_is_set() {
            s
        } else {
            s.with_local(LocalSearch::Simplex)
        }
    }

    /// The search box of the base parameters: the certificate's widened one where the run
    /// has one, else the problem's.
    fn base_bounds(&self) -> Vec<(f64, f64)> {
        match &self.result.certificate {
            Some(c) => c.bounds.clone(),
            None => self
                .experiment
                .params()
                .params
                .iter()
                .map(|p| (p.lower, p.upper))
                .collect(),
        }
    }

    /// Each fixed parameter freed.
    pub(super) fn free_fixed(&self) -> Result<Vec<Explanation>, TuneError> {
        let r = self.result;
        let mut out = Vec::new();
        for (i, p) in self.experiment.params().params.iter().enumerate() {
            if !r.fixed[i] {
                continue;
            }
            // The freed parameter's box widened as the certificate widens a free one's: a
            // value held fixed says nothing of where the data want it.
            let mut bounds = self.base_bounds();
            bounds[i] = (bounds[i].0 / WIDEN, bounds[i].1 * WIDEN);
            let wide = Rebounded::new(self.experiment, &bounds);
            let mut fixed = r.fixed.clone();
            fixed[i] = false;
            // From the best fit, and from the designer's values with the fixed one as it
            // was (the best fit moved the others to make up for it, maybe out of the basin
            // where the freed one fits: measured, an r held at ÷7 of its truth).
            let mut designer = r.initial.clone();
            designer[i] = r.tuned[i];
            let t = self.fit(&wide, [r.tuned.clone(), designer], &fixed)?;
            let s = self.settings_for();
            let mut trial = trial(format!("freeing {}", p.name), &wide, &t, s.nis_only());
            trial.neutral = (t.tuned[i] / r.tuned[i]).ln().abs() <= 0.02;
            out.push(Explanation {
                cause: Cause::FixedParameter,
                subject: p.name.clone(),
                evidence: format!(
                    "fitted {} = {} (fixed at {})",
                    p.name,
                    fmt_value(t.tuned[i]),
                    fmt_value(r.tuned[i])
                ),
                remedy: format!(
                    "set {} to about {} (it was fixed at {})",
                    p.name,
                    with_unit(t.tuned[i], &p.unit),
                    fmt_value(r.tuned[i])
                ),
                trial: Some(trial),
                untried: None,
                added: 1,
            });
        }
        Ok(out)
    }

    /// Each hypothesis about the filter's model, where the experiment holds its model as
    /// matrices (a linear problem); not tried, and said so, elsewhere.
    pub(super) fn hypotheses(&self) -> Result<Vec<Explanation>, TuneError> {
        // The trials do not depend on each other: side by side, booked in their order.
        use rayon::prelude::*;
        let Some(lin) = self.experiment.linear() else {
            // A filter held as code: where autotune feeds it its readings, what it reads
            // can be changed (a sensor's offset or gain); its model cannot.
            let e = self.experiment;
            let scales = e.innovation_scales(&self.result.tuned, e.mc());
            return Hypothesis::ALL
                .par_iter()
                .map(|&h| match scales.as_deref().and_then(|s| ReadThrough::new(e, h, s)) {
                    Some(read) => self.run(&read),
                    None if scales.is_some() => Ok(untried(h, "autotune holds this filter's model as code: it can change what the filter reads (a sensor's offset or gain), not its model")),
                    None => Ok(untried(h, "autotune holds this filter's model as code, not as matrices it can change (only a linear problem's filter can be changed)")),
                })
                .collect();
        };
        Hypothesis::ALL
            .par_iter()
            .map(|&h| match Hypothesized::new(lin, h, &self.result.tuned) {
                Some(e) => self.run(&e),
                None => Ok(untried(h, inexpressible(h))),
            })
            .collect()
    }

    /// The trial of hypothesis experiment `e`, from the run's best fit and the change's
    /// own starting values.
    fn run(&self, e: &dyn Changed) -> Result<Explanation, TuneError> {
        let r = self.result;
        let h = e.hypothesis();
        let mut bounds = self.base_bounds();
        bounds.extend(e.added().iter().map(|a| (a.def.lower, a.def.upper)));
        let wide = Rebounded::new(e as &dyn Experiment, &bounds);
        let mut fixed = r.fixed.clone();
        fixed.extend(e.added().iter().map(|_| false));
        let s = self.settings_for();
        let neutral: Vec<f64> = e.added().iter().map(|a| a.def.value).collect();
        let starts = [&r.tuned, &r.initial].map(|base| {
            let mut start = base.clone();
            start.extend(&neutral);
            start
        });
        let mut t = self.fit(&wide, starts.clone(), &fixed)?;
        if h == Hypothesis::ColouredNoise && t.confirmation.holds() {
            // A fit whose every correlation outlasts the run is a bias drawn per run, and
            // says nothing of noise that decays within it; whether such noise fits too
            // (measured: φ 0.64 on a weak coloured part, fit at 0.999 beside a bias) is
            // what tells the data's two readings apart, so it is fitted with each
            // correlation held to at most half the run.
            let corr: Vec<usize> = (0..bounds.len())
                .filter(|&i| wide.params().params[i].name.starts_with("gm_corr_"))
                .collect();
            let slow = slow_correlation(self.mc.steps());
            if corr.iter().all(|&i| t.tuned[i] >= slow) {
                let mut within = bounds.clone();
                let half = 1.0 - 2.0 / self.mc.steps().max(2) as f64;
                for &i in &corr {
                    within[i].1 = within[i].1.min(half).max(within[i].0);
                }
                let fast = Rebounded::new(e as &dyn Experiment, &within);
                let decays = self.fit(&fast, starts, &fixed)?;
                if decays.confirmation.holds() {
                    t = decays;
                }
            }
        }
        let mut tr = trial(format!("fitting {}", e.words()), &wide, &t, s.nis_only());
        tr.neutral = e.at_neutral(&t.tuned);
        let (subject, evidence, remedy) = read(e, &tr);
        Ok(Explanation {
            cause: Cause::Model(h),
            subject,
            evidence,
            remedy,
            trial: Some(tr),
            untried: None,
            added: e.added().len(),
        })
    }

    /// The fit of a changed experiment `wide` from the run's best fit, then from the
    /// designer's values (`starts`, the change at its neutral value in both), stopping at
    /// the first whose confirmation holds; the better of those tried otherwise.
    ///
    /// From each start a first look on a small budget; a look that comes well below the
    /// unchanged filter's best is searched in full from where it ended, and polished by
    /// Levenberg–Marquardt where that does not hold.
    fn fit(
        &self,
        wide: &dyn Experiment,
        starts: [Vec<f64>; 2],
        fixed: &[bool],
    ) -> Result<TuneResult, TuneError> {
        let r = self.result;
        let s = self.settings_for();
        let look_budget = LOOK_EVALS.max(LOOK_PER_PARAM * fixed.iter().filter(|f| !**f).count());
        let look_settings = s
            .clone()
            .with_max_evals(look_budget)
            .expect("a budget of at least one evaluation");
        let mut best: Option<TuneResult> = None;
        let keep = |t: TuneResult, best: &mut Option<TuneResult>| {
            let holds = t.confirmation.holds();
            if best
                .as_ref()
                .is_none_or(|b| better(&t, b) == std::cmp::Ordering::Less)
            {
                *best = Some(t);
            }
            holds
        };
        let gains = |t: &TuneResult| t.objective_final.total < LOOK_GAIN * r.objective_final.total;
        for start in starts {
            let look = tune(wide, &start, fixed, self.mc, &look_settings, &Silent)?;
            let mut promising = gains(&look);
            let exact = look.scoring == Scoring::Exact;
            let mut from = look.tuned.clone();
            if keep(look, &mut best) {
                break;
            }
            // A simplex's look in a dozen dimensions can find the change and leave the
            // noise parameters where they started (measured: a misalignment's angle found
            // to 0.004 rad from the designer's values, with q and r still ×5 off and the
            // score no better than the unchanged filter's). Where evaluations are exact,
            // and so cheap, Levenberg–Marquardt sets those in a few Jacobians, and the
            // look is judged by where it ends.
            if !promising && exact && !self.settings.local_is_set() {
                let lm = look_settings.clone().with_local(LocalSearch::GaussNewton);
                let t = tune(wide, &from, fixed, self.mc, &lm, &Silent)?;
                promising = gains(&t);
                from = t.tuned.clone();
                if keep(t, &mut best) {
                    break;
                }
            }
            if promising {
                let t = tune(wide, &from, fixed, self.mc, &s, &Silent)?;
                // The simplex finds the change's basin but in a dozen dimensions may end
                // its budget short of the floor (measured: a misalignment fit to 0.2° of
                // its truth at score 0.013, 1 of 12 seeds passing); Levenberg–Marquardt
                // from there converges in a few Jacobians.
                let polish = !t.confirmation.holds() && !self.settings.local_is_set();
                let end = t.tuned.clone();
                if keep(t, &mut best) {
                    break;
                }
                if polish {
                    let p = s.clone().with_local(LocalSearch::GaussNewton);
                    let t = tune(wide, &end, fixed, self.mc, &p, &Silent)?;
                    let (end, again) = (t.tuned.clone(), exact && gains(&t));
                    if keep(t, &mut best) {
                        break;
                    }
                    // Where the polish stalls in a valley its Jacobian cannot follow, the
                    // simplex from its end goes on, and the polish after it (measured: a
                    // misalignment at J 0.05 with r ×3 off, fit to J < 1e-5 by a second
                    // simplex). One more round, where evaluations are cheap.
                    if again {
                        let t = tune(wide, &end, fixed, self.mc, &s, &Silent)?;
                        let end = t.tuned.clone();
                        if keep(t, &mut best) {
                            break;
                        }
                        let t = tune(wide, &end, fixed, self.mc, &p, &Silent)?;
                        if keep(t, &mut best) {
                            break;
                        }
                    }
                }
            }
        }
        Ok(best.expect("two starts tried"))
    }
}

/// `a` before `b` when it is the better trial: its confirmation holds where `b`'s does not,
/// or, alike in that, a lower score.
pub(super) fn better(a: &TuneResult, b: &TuneResult) -> std::cmp::Ordering {
    b.confirmation
        .holds()
        .cmp(&a.confirmation.holds())
        .then(a.objective_final.total.total_cmp(&b.objective_final.total))
}

/// Why a filter cannot express `h` ([`Hypothesized::new`] gave none).
pub(super) fn inexpressible(h: Hypothesis) -> &'static str {
    match h {
        Hypothesis::TimeStep | Hypothesis::NoiseKind => {
            "this filter's F has no real logarithm, so no other step can be built from it"
        }
        Hypothesis::MotionState => {
            "this filter's F has no real logarithm, or no process-noise parameter drives an input"
        }
        Hypothesis::MeasurementMatrix | Hypothesis::FullR => {
            "this filter has one measurement component: nothing to mix or correlate"
        }
        _ => "this filter cannot express it",
    }
}

/// A hypothesis not tried, and why.
fn untried(h: Hypothesis, why: &str) -> Explanation {
    Explanation {
        cause: Cause::Model(h),
        subject: h.place().to_string(),
        evidence: String::new(),
        remedy: String::new(),
        trial: None,
        untried: Some(why.to_string()),
        added: 0,
    }
}

fn trial(change: String, e: &dyn Experiment, t: &TuneResult, nis_only: bool) -> Trial {
    let values: Vec<(String, f64)> = e
        .params()
        .params
        .iter()
        .zip(&t.tuned)
        .map(|(p, v)| (p.name.clone(), *v))
        .collect();
    Trial {
        change,
        status: t.status,
        passed: t.confirmation.passed,
        seeds: t.confirmation.seeds,
        band_low: t.confirmation.band_low,
        values,
        evaluations: t.evaluations + t.refine_evaluations,
        score: t.objective_final.total,
        neutral: false,
        nis_only,
        recorded: t.confirmation.recorded,
        same_as: None,
    }
}

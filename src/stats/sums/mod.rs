//! The sufficient statistics of a Monte Carlo evaluation: sums over runs that the engines
//! fill and the report, the objective and the tuner read.

use serde::Serialize;

use super::{SumVariance, Verdict};

mod read;

/// How many divergences are kept with their details.
const MAX_DIVERGENCES: usize = 10;

/// Why a run stopped before its last step.
#[derive(Debug, Clone, Copy, Serialize, PartialEq, Eq)]
#[serde(rename_all = "snake_case")]
pub enum StopCause {
    /// The filter broke down: a covariance stopped being positive definite, a measurement
    /// did not fit, or its error left its covariance by more than 1e154 standard deviations.
    Diverged,
    /// A covariance the filter inverts (P⁻, S or P) was too ill-conditioned for its NEES,
    /// NIS or gain to keep their digits: the numbers would be rounding noise.
    IllConditioned,
    /// The truth state overflowed, or outgrew double precision relative to the filter's
    /// standard deviations: the truth model is unstable over this horizon, and nothing about
    /// the filter can be computed.
    TruthOverflow,
}

/// A run that stopped early, and why.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Divergence {
    /// Run index (0-based).
    pub run: usize,
    /// Time step (1-based).
    pub step: usize,
    /// The kind of stop, which sets the report's verdict.
    pub cause: StopCause,
    /// What failed, in words.
    pub reason: String,
}

/// Sufficient statistics of a Monte Carlo evaluation, summed over runs.
///
/// Per-step vectors have length T (index k − 1 for step k); component vectors have length
/// n_x or n_z (all sensors' components concatenated in sensor order); whiteness vectors
/// have length `lags · n_z`, lag-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Accumulator {
    /// Runs completed or diverged.
    pub(crate) runs: usize,
    /// Steps per run.
    pub(crate) steps: usize,
    /// Largest autocorrelation lag.
    pub(crate) lags: usize,
    /// Σ_i NEES_ik.
    pub(crate) nees_sum: Vec<f64>,
    /// Σ_i NEES_ik².
    pub(crate) nees_sq: Vec<f64>,
    /// Σ_i n_x (degrees of freedom of the step's NEES sum).
    pub(crate) nees_dof: Vec<f64>,
    /// Number of runs contributing a NEES at the step.
    pub(crate) nees_count: Vec<f64>,
    /// Σ over the runs counted in `null_var_runs` of the variance of the per-run NEES sum
    /// the filter predicts under consistency (see `super::NeesNullVariance`); read it through
    /// [`Accumulator::nees_null_variance`].
    pub(crate) nees_null_var: f64,
    /// Runs whose predicted NEES-sum variance is in `nees_null_var`: all of them on the
    /// linear and exact paths, every `NULL_VAR_STRIDE`-th on the generic one
    /// (`crate::montecarlo::NULL_VAR_STRIDE`).
    pub(crate) null_var_runs: usize,
    /// Runs sampled for the predicted variance whose filter supplied no error map
    /// (`crate::filter::Estimate::error_map`); when any did, the gate takes the NEES-sum
    /// variance from the spread of the per-run sums instead.
    pub(crate) error_map_missing: usize,
    /// Σ over finished runs i of the run's NEES sum `S_i = Σ_k ε_ik`.
    pub(crate) nees_run_total: f64,
    /// Σ over finished runs of `S_i²`.
    pub(crate) nees_run_total_sq: f64,
    /// Finished runs behind `nees_run_total` (0 on the exact path, which has no runs).
    pub(crate) nees_total_runs: usize,
    /// Σ_i NIS_ik.
    pub(crate) nis_sum: Vec<f64>,
    /// Σ_i NIS_ik².
    pub(crate) nis_sq: Vec<f64>,
    /// Σ_i n_z,ik (the dimension of the measurement each run used at the step).
    pub(crate) nis_dof: Vec<f64>,
    /// Number of runs with a measurement at the step.
    pub(crate) nis_count: Vec<f64>,
    /// Σ_{i,k} e_j²/P_jj per state component.
    pub(crate) state_comp_total: Vec<f64>,
    /// Samples behind `state_comp_total`.
    pub(crate) state_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of e_j²/P_jj.
    pub(crate) state_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub(crate) state_comp_run_sq: Vec<f64>,
    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// of e_j²/P_jj that the filter predicts under consistency (see
    /// `super::ComponentNullVariance`).
    pub(crate) state_comp_null_var: Vec<f64>,
    /// Runs whose predicted component variances are in `state_comp_null_var` (computed for
    /// the full gate only, on the same runs as the NEES-sum variance).
    pub(crate) comp_null_var_runs: usize,
    /// Σ_{i,k} e_j/√P_jj per state component (n_x): the first moment, 0 in expectation
    /// for a consistent filter. Linear in the data, so a difference of two evaluations with
    /// common random numbers is smooth in a sensor offset.
    pub(crate) state_mean_total: Vec<f64>,
    /// Samples behind `state_mean_total`: as `state_comp_samples`, except for records that
    /// give only `e_j²/P_jj` (no sign), which leave it 0 and get no zero-mean test.
    pub(crate) state_mean_samples: Vec<f64>,
    /// Σ over finished runs i of the square of the run's own sum `Σ_k e_j/√P_jj` (n_x): the
    /// run-to-run spread, the null variance of `state_mean_total` for a filter that supplies
    /// no error map.
    pub(crate) state_mean_run_sq: Vec<f64>,
    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// `Σ_k e_jk/√P_jj,k` that a consistent filter predicts (n_x; see
    /// `super::ComponentNullVariance::mean_variances`).
    pub(crate) state_mean_null_var: Vec<f64>,
    /// Σ_{i,k} ν_j/√S_jj per measurement component (n_z). Innovations of a consistent filter
    /// are white, so its null variance is exactly its sample count, `meas_comp_samples`.
    pub(crate) meas_mean_total: Vec<f64>,
    /// Σ over finished runs i of the square of the run's own sum `Σ_k ν_j/√S_jj` (n_z): the
    /// run-to-run spread, the zero-mean test's variance whether or not the filter is
    /// consistent.
    pub(crate) meas_mean_run_sq: Vec<f64>,
    /// Σ_{i,k} ν_j²/S_jj per measurement component.
    pub(crate) meas_comp_total: Vec<f64>,
    /// Samples behind `meas_comp_total`.
    pub(crate) meas_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of ν_j²/S_jj.
    pub(crate) meas_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub(crate) meas_comp_run_sq: Vec<f64>,
    /// Runs in which the component was measured at least once.
    pub(crate) meas_comp_runs: Vec<usize>,
    /// Σ u_k u_{k−l} with u = ν_j/√S_jj.
    pub(crate) white_ab: Vec<f64>,
    /// Σ u_k².
    pub(crate) white_a2: Vec<f64>,
    /// Σ u_{k−l}².
    pub(crate) white_b2: Vec<f64>,
    /// Number of pairs.
    pub(crate) white_pairs: Vec<f64>,
    /// Number of runs that stopped early, for any `StopCause`.
    pub(crate) diverged_runs: usize,
    /// Of those, the runs stopped by an ill-conditioned covariance.
    pub(crate) ill_conditioned_runs: usize,
    /// Of those, the runs stopped by a truth state that overflowed.
    pub(crate) truth_overflow_runs: usize,
    /// The first few divergences, by run index.
    pub(crate) divergences: Vec<Divergence>,
}

impl Accumulator {
    /// Zeroed sums for T steps, n_x states, n_z measurement components and `lags` lags.
    pub fn new(steps: usize, n_x: usize, n_z: usize, lags: usize) -> Self {
        let z = |len| vec![0.0; len];
        Accumulator {
            runs: 0,
            steps,
            lags,
            nees_sum: z(steps),
            nees_sq: z(steps),
            nees_dof: z(steps),
            nees_count: z(steps),
            nees_null_var: 0.0,
            null_var_runs: 0,
            error_map_missing: 0,
            nees_run_total: 0.0,
            nees_run_total_sq: 0.0,
            nees_total_runs: 0,
            nis_sum: z(steps),
            nis_sq: z(steps),
            nis_dof: z(steps),
            nis_count: z(steps),
            state_comp_total: z(n_x),
            state_comp_samples: z(n_x),
            state_comp_run_sum: z(n_x),
            state_comp_run_sq: z(n_x),
            state_comp_null_var: z(n_x),
            comp_null_var_runs: 0,
            state_mean_total: z(n_x),
            state_mean_samples: z(n_x),
            state_mean_run_sq: z(n_x),
            state_mean_null_var: z(n_x),
            meas_mean_total: z(n_z),
            meas_mean_run_sq: z(n_z),
            meas_comp_total: z(n_z),
            meas_comp_samples: z(n_z),
            meas_comp_run_sum: z(n_z),
            meas_comp_run_sq: z(n_z),
            meas_comp_runs: vec![0; n_z],
            white_ab: z(lags * n_z),
            white_a2: z(lags * n_z),
            white_b2: z(lags * n_z),
            white_pairs: z(lags * n_z),
            diverged_runs: 0,
            ill_conditioned_runs: 0,
            truth_overflow_runs: 0,
            divergences: Vec::new(),
        }
    }

    /// The variance of the NEES sum over all runs that the filters predict under
    /// consistency: the sampled runs' mean, times the runs that finished.
    pub fn nees_null_variance(&self) -> f64 {
        if self.null_var_runs == 0 {
            return 0.0;
        }
        let finished = self.runs.saturating_sub(self.diverged_runs);
        self.nees_null_var * finished as f64 / self.null_var_runs as f64
    }

    /// Add one run's NEES `nees` with `dof` degrees of freedom at step index `i` (step i + 1).
    pub fn add_nees(&mut self, i: usize, nees: f64, dof: f64) {
        self.nees_sum[i] += nees;
        self.nees_sq[i] += nees * nees;
        self.nees_dof[i] += dof;
        self.nees_count[i] += 1.0;
    }

    /// Add one run's NIS `nis` with `dof` degrees of freedom (the step's measurement
    /// dimension) at step index `i` (step i + 1).
    pub fn add_nis(&mut self, i: usize, nis: f64, dof: f64) {
        self.nis_sum[i] += nis;
        self.nis_sq[i] += nis * nis;
        self.nis_dof[i] += dof;
        self.nis_count[i] += 1.0;
    }

    /// Add one finished run's NEES sum `S_i = Σ_k ε_ik`.
    pub fn add_run_nees_total(&mut self, total: f64) {
        self.nees_run_total += total;
        self.nees_run_total_sq += total * total;
        self.nees_total_runs += 1;
    }

    /// Whether the predicted NEES-sum variance covers the runs: every sampled filter
    /// supplied its error map, and at least one run was sampled.
    pub fn has_nees_null_variance(&self) -> bool {
        self.error_map_missing == 0 && self.null_var_runs > 0
    }

    /// The variance of the NEES sum over all runs estimated from the spread of the per-run
    /// sums, `N s²` with `s²` their sample variance, and the runs it rests on; `None` below
    /// two runs.
    pub fn nees_spread_variance(&self) -> Option<(f64, usize)> {
        let n = self.nees_total_runs;
        if n < 2 {
            return None;
        }
        let nf = n as f64;
        let mean = self.nees_run_total / nf;
        let s2 = ((self.nees_run_total_sq - nf * mean * mean) / (nf - 1.0)).max(0.0);
        Some((nf * s2, n))
    }

    /// What the variance of the NEES sum over all runs rests on: the filters' own
    /// prediction where every sampled filter supplied its error map, else the spread of the
    /// per-run sums, else (one run: a single recording) batch means over its steps
    /// ([`super::interval::batch_spread`] on the per-step sums).
    pub fn nees_sum_variance(&self) -> SumVariance {
        if self.has_nees_null_variance() {
            return SumVariance::Predicted(self.nees_null_variance());
        }
        if let Some((var, runs)) = self.nees_spread_variance() {
            return SumVariance::RunSpread { var, runs };
        }
        let series: Vec<f64> = self
            .nees_sum
            .iter()
            .zip(&self.nees_count)
            .filter(|(_, c)| **c > 0.0)
            .map(|(s, _)| *s)
            .collect();
        match super::interval::batch_spread(&series) {
            Some((var, batches)) => SumVariance::BatchSpread { var, batches },
            None => SumVariance::Unavailable,
        }
    }

    /// Add one run's time average `a` of component j's normalized squared error (state or
    /// measurement) to the per-run sums.
    pub fn add_run_component(&mut self, state: bool, j: usize, a: f64) {
        let (sum, sq) = if state {
            (&mut self.state_comp_run_sum, &mut self.state_comp_run_sq)
        } else {
            (&mut self.meas_comp_run_sum, &mut self.meas_comp_run_sq)
        };
        sum[j] += a;
        sq[j] += a * a;
    }

    /// What the variance of state component j's sum over all runs and steps rests on: the
    /// filters' own prediction where every sampled filter supplied its error map, else the
    /// spread of the per-run averages (each of `steps` samples) across the finished runs.
    pub fn state_component_variance(&self, j: usize) -> SumVariance {
        let finished = self.runs.saturating_sub(self.diverged_runs);
        if self.error_map_missing == 0 && self.comp_null_var_runs > 0 {
            let scale = finished as f64 / self.comp_null_var_runs as f64;
            return SumVariance::Predicted(self.state_comp_null_var[j] * scale);
        }
        if finished < 2 {
            return SumVariance::Unavailable;
        }
        let n = finished as f64;
        let mean = self.state_comp_run_sum[j] / n;
        let var_avg = ((self.state_comp_run_sq[j] - n * mean * mean) / (n - 1.0)).max(0.0);
        let t = self.steps as f64;
        SumVariance::RunSpread {
            var: n * t * t * var_avg,
            runs: finished,
        }
    }

    /// What the variance of state component j's first-moment sum `state_mean_total[j]`
    /// rests on: `N s²`, with `s²` the sample variance of the per-run sums about their mean
    /// (about the mean, so that a bias does not inflate its own yardstick). The spread
    /// needs no consistency: errors that are zero-mean but correlated in time (a bias drawn
    /// per run, coloured noise, a filter that is off) spread the per-run sums as much as
    /// they spread the total, where the filter's own prediction would not (issue 38: z had
    /// a standard deviation of 6 there). Below two finished runs there is no spread, and
    /// the variance is the filters' own prediction where every sampled filter supplied its
    /// error map (valid only for a consistent filter), else unavailable.
    pub fn state_mean_variance(&self, j: usize) -> SumVariance {
        let finished = self.runs.saturating_sub(self.diverged_runs);
        let v = spread(
            self.state_mean_total[j],
            self.state_mean_run_sq[j],
            finished,
        );
        if matches!(v, SumVariance::Unavailable)
            && self.error_map_missing == 0
            && self.comp_null_var_runs > 0
        {
            let scale = finished as f64 / self.comp_null_var_runs as f64;
            return SumVariance::Predicted(self.state_mean_null_var[j] * scale);
        }
        v
    }

    /// What the variance of measurement component j's first-moment sum
    /// `meas_mean_total[j]` rests on: as [`Self::state_mean_variance`], over the runs in
    /// which the component was measured. A single run (a recording) has no spread; its
    /// variance is then the sample count, what white innovations of a consistent filter
    /// give.
    pub fn meas_mean_variance(&self, j: usize) -> SumVariance {
        match spread(
            self.meas_mean_total[j],
            self.meas_mean_run_sq[j],
            self.meas_comp_runs[j],
        ) {
            SumVariance::Unavailable => SumVariance::Predicted(self.meas_comp_samples[j]),
            v => v,
        }
    }

    /// Add another accumulator's sums to this one.
    pub fn merge(&mut self, o: &Accumulator) {
        fn add(a: &mut [f64], b: &[f64]) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
        self.runs += o.runs;
        add(&mut self.nees_sum, &o.nees_sum);
        add(&mut self.nees_sq, &o.nees_sq);
        add(&mut self.nees_dof, &o.nees_dof);
        add(&mut self.nees_count, &o.nees_count);
        self.nees_null_var += o.nees_null_var;
        self.null_var_runs += o.null_var_runs;
        self.error_map_missing += o.error_map_missing;
        self.nees_run_total += o.nees_run_total;
        self.nees_run_total_sq += o.nees_run_total_sq;
        self.nees_total_runs += o.nees_total_runs;
        add(&mut self.nis_sum, &o.nis_sum);
        add(&mut self.nis_sq, &o.nis_sq);
        add(&mut self.nis_dof, &o.nis_dof);
        add(&mut self.nis_count, &o.nis_count);
        add(&mut self.state_comp_total, &o.state_comp_total);
        add(&mut self.state_comp_samples, &o.state_comp_samples);
        add(&mut self.state_comp_run_sum, &o.state_comp_run_sum);
        add(&mut self.state_comp_run_sq, &o.state_comp_run_sq);
        add(&mut self.state_comp_null_var, &o.state_comp_null_var);
        self.comp_null_var_runs += o.comp_null_var_runs;
        add(&mut self.state_mean_total, &o.state_mean_total);
        add(&mut self.state_mean_samples, &o.state_mean_samples);
        add(&mut self.state_mean_run_sq, &o.state_mean_run_sq);
        add(&mut self.state_mean_null_var, &o.state_mean_null_var);
        add(&mut self.meas_mean_total, &o.meas_mean_total);
        add(&mut self.meas_mean_run_sq, &o.meas_mean_run_sq);
        add(&mut self.meas_comp_total, &o.meas_comp_total);
        add(&mut self.meas_comp_samples, &o.meas_comp_samples);
        add(&mut self.meas_comp_run_sum, &o.meas_comp_run_sum);
        add(&mut self.meas_comp_run_sq, &o.meas_comp_run_sq);
        for (a, b) in self.meas_comp_runs.iter_mut().zip(&o.meas_comp_runs) {
            *a += b;
        }
        add(&mut self.white_ab, &o.white_ab);
        add(&mut self.white_a2, &o.white_a2);
        add(&mut self.white_b2, &o.white_b2);
        add(&mut self.white_pairs, &o.white_pairs);
        self.diverged_runs += o.diverged_runs;
        self.ill_conditioned_runs += o.ill_conditioned_runs;
        self.truth_overflow_runs += o.truth_overflow_runs;
        let room = MAX_DIVERGENCES.saturating_sub(self.divergences.len());
        self.divergences
            .extend(o.divergences.iter().take(room).cloned());
    }

    /// Count run `run` as diverged at `step` (0 if not tied to a step) for `reason`; the
    /// first few are kept with their details.
    pub fn record_divergence(&mut self, run: usize, step: usize, reason: String) {
        self.record_stop(run, step, StopCause::Diverged, reason);
    }

    /// Count run `run` as stopped at `step` (0 if not tied to a step) by `cause`, for
    /// `reason`; the first few are kept with their details.
    pub fn record_stop(&mut self, run: usize, step: usize, cause: StopCause, reason: String) {
        self.diverged_runs += 1;
        match cause {
            StopCause::Diverged => {}
            StopCause::IllConditioned => self.ill_conditioned_runs += 1,
            StopCause::TruthOverflow => self.truth_overflow_runs += 1,
        }
        if self.divergences.len() < MAX_DIVERGENCES {
            self.divergences.push(Divergence {
                run,
                step,
                cause,
                reason,
            });
        }
    }

    /// The verdict the runs that stopped early impose, if any: a truth overflow before an
    /// ill-conditioned covariance before a divergence (the first makes the others
    /// meaningless; the second is a numerical, not a statistical, failure).
    pub fn stop_verdict(&self) -> Option<Verdict> {
        if self.truth_overflow_runs > 0 {
            Some(Verdict::TruthOverflow)
        } else if self.ill_conditioned_runs > 0 {
            Some(Verdict::IllConditioned)
        } else if self.diverged_runs > 0 {
            Some(Verdict::Diverged)
        } else {
            None
        }
    }
}

/// `N s²` for a sum over `runs` runs of per-run sums whose squares add to `run_sq`: the
/// run-to-run spread about the mean; unavailable below two runs.
fn spread(total: f64, run_sq: f64, runs: usize) -> SumVariance {
    if runs < 2 {
        return SumVariance::Unavailable;
    }
    let n = runs as f64;
    let mean = total / n;
    let s2 = ((run_sq - n * mean * mean) / (n - 1.0)).max(0.0);
    SumVariance::RunSpread { var: n * s2, runs }
}

#[cfg(test)]
mod merge_properties {
    //! Monte Carlo sums merge associatively and add every field: the engine relies on it to
    //! give the same result whatever the chunking.

    use super::*;
    use proptest::prelude::*;

    proptest! {
    /// `(a + b) + c == a + (b + c)` exactly, on sums whose values are small integers (exact
    /// in floating point, so any field merged wrongly, twice or not at all shows).
    #[test]
    fn sums_merge_associatively(
        va in proptest::collection::vec(0u32..100, 64),
        vb in proptest::collection::vec(0u32..100, 64),
        vc in proptest::collection::vec(0u32..100, 64),
    ) {
        let a = accumulator(&va);
        let b = accumulator(&vb);
        let c = accumulator(&vc);
        let mut left = a.clone();
        left.merge(&b);
        left.merge(&c);
        let mut bc = b.clone();
        bc.merge(&c);
        let mut right = a.clone();
        right.merge(&bc);
        prop_assert_eq!(&left, &right);
        // And merging adds every sum (associativity alone would not see a field that is
        // never merged).
        let (sa, sb, sc, sl) = (scalars(&a), scalars(&b), scalars(&c), scalars(&left));
        for i in 0..sl.len() {
            prop_assert_eq!(sl[i], sa[i] + sb[i] + sc[i], "scalar {}", i);
        }
        let (va, vb, vc, vl) = (vectors(&a), vectors(&b), vectors(&c), vectors(&left));
        for (k, l) in vl.iter().enumerate() {
            for j in 0..l.len() {
                prop_assert_eq!(l[j], va[k][j] + vb[k][j] + vc[k][j], "vector {} [{}]", k, j);
            }
        }
    }
    }

    /// Every scalar sum of `acc`, as f64.
    fn scalars(acc: &Accumulator) -> Vec<f64> {
        vec![
            acc.runs as f64,
            acc.nees_null_var,
            acc.null_var_runs as f64,
            acc.error_map_missing as f64,
            acc.nees_run_total,
            acc.nees_run_total_sq,
            acc.nees_total_runs as f64,
            acc.diverged_runs as f64,
            acc.meas_comp_runs[0] as f64,
            acc.meas_comp_runs[1] as f64,
        ]
    }

    /// Every vector sum of `acc`.
    fn vectors(acc: &Accumulator) -> Vec<Vec<f64>> {
        let mut a = acc.clone();
        fields(&mut a).into_iter().map(|v| v.clone()).collect()
    }

    /// The vector sums of `acc`, for filling and for checking.
    fn fields(acc: &mut Accumulator) -> [&mut Vec<f64>; 27] {
        [
            &mut acc.nees_sum,
            &mut acc.nees_sq,
            &mut acc.nees_dof,
            &mut acc.nees_count,
            &mut acc.nis_sum,
            &mut acc.nis_sq,
            &mut acc.nis_dof,
            &mut acc.nis_count,
            &mut acc.state_comp_total,
            &mut acc.state_comp_samples,
            &mut acc.state_comp_run_sum,
            &mut acc.state_comp_run_sq,
            &mut acc.state_comp_null_var,
            &mut acc.state_mean_total,
            &mut acc.state_mean_samples,
            &mut acc.state_mean_run_sq,
            &mut acc.state_mean_null_var,
            &mut acc.meas_mean_total,
            &mut acc.meas_mean_run_sq,
            &mut acc.meas_comp_total,
            &mut acc.meas_comp_samples,
            &mut acc.meas_comp_run_sum,
            &mut acc.meas_comp_run_sq,
            &mut acc.white_ab,
            &mut acc.white_a2,
            &mut acc.white_b2,
            &mut acc.white_pairs,
        ]
    }

    /// An accumulator of 3 steps, 2 states, 2 measurement components and 2 lags, every field
    /// filled from `v` (cycled), with up to 7 divergences.
    fn accumulator(v: &[u32]) -> Accumulator {
        let mut acc = Accumulator::new(3, 2, 2, 2);
        let mut it = v.iter().cycle().map(|&x| f64::from(x));
        let mut fill = |xs: &mut Vec<f64>| xs.iter_mut().for_each(|x| *x = it.next().unwrap());
        for xs in fields(&mut acc) {
            fill(xs);
        }
        acc.runs = v[0] as usize;
        acc.nees_null_var = f64::from(v[1]);
        acc.null_var_runs = v[2] as usize;
        acc.error_map_missing = v[3] as usize % 3;
        acc.nees_run_total = f64::from(v[4]);
        acc.nees_run_total_sq = f64::from(v[5]);
        acc.nees_total_runs = v[6] as usize;
        acc.meas_comp_runs = vec![v[7] as usize, v[8] as usize];
        for i in 0..(v[9] as usize % 8) {
            acc.record_divergence(i, v[10 + i] as usize, format!("reason {i}"));
        }
        acc
    }

    /// Each reader gives its own sum: the fields hold distinct values, so a reader that
    /// gave another field's sum, or a default, fails here by name.
    #[test]
    fn every_reader_gives_its_own_sum() {
        let v: Vec<u32> = (2..=65).collect();
        let mut acc = accumulator(&v);
        acc.comp_null_var_runs = 65;
        acc.ill_conditioned_runs = 66;
        acc.truth_overflow_runs = 67;
        acc.lags = 68;
        assert_eq!(acc.runs(), acc.runs, "runs");
        assert_eq!(acc.steps(), acc.steps, "steps");
        assert_eq!(acc.lags(), acc.lags, "lags");
        assert_eq!(acc.nees_sum(), &acc.nees_sum[..], "nees_sum");
        assert_eq!(acc.nees_sq(), &acc.nees_sq[..], "nees_sq");
        assert_eq!(acc.nees_dof(), &acc.nees_dof[..], "nees_dof");
        assert_eq!(acc.nees_count(), &acc.nees_count[..], "nees_count");
        assert_eq!(acc.nees_null_var(), acc.nees_null_var, "nees_null_var");
        assert_eq!(acc.null_var_runs(), acc.null_var_runs, "null_var_runs");
        assert_eq!(
            acc.error_map_missing(),
            acc.error_map_missing,
            "error_map_missing"
        );
        assert_eq!(acc.nees_run_total(), acc.nees_run_total, "nees_run_total");
        assert_eq!(
            acc.nees_run_total_sq(),
            acc.nees_run_total_sq,
            "nees_run_total_sq"
        );
        assert_eq!(
            acc.nees_total_runs(),
            acc.nees_total_runs,
            "nees_total_runs"
        );
        assert_eq!(acc.nis_sum(), &acc.nis_sum[..], "nis_sum");
        assert_eq!(acc.nis_sq(), &acc.nis_sq[..], "nis_sq");
        assert_eq!(acc.nis_dof(), &acc.nis_dof[..], "nis_dof");
        assert_eq!(acc.nis_count(), &acc.nis_count[..], "nis_count");
        assert_eq!(
            acc.state_comp_total(),
            &acc.state_comp_total[..],
            "state_comp_total"
        );
        assert_eq!(
            acc.state_comp_samples(),
            &acc.state_comp_samples[..],
            "state_comp_samples"
        );
        assert_eq!(
            acc.state_comp_run_sum(),
            &acc.state_comp_run_sum[..],
            "state_comp_run_sum"
        );
        assert_eq!(
            acc.state_comp_run_sq(),
            &acc.state_comp_run_sq[..],
            "state_comp_run_sq"
        );
        assert_eq!(
            acc.state_comp_null_var(),
            &acc.state_comp_null_var[..],
            "state_comp_null_var"
        );
        assert_eq!(
            acc.comp_null_var_runs(),
            acc.comp_null_var_runs,
            "comp_null_var_runs"
        );
        assert_eq!(
            acc.state_mean_total(),
            &acc.state_mean_total[..],
            "state_mean_total"
        );
        assert_eq!(
            acc.state_mean_samples(),
            &acc.state_mean_samples[..],
            "state_mean_samples"
        );
        assert_eq!(
            acc.state_mean_run_sq(),
            &acc.state_mean_run_sq[..],
            "state_mean_run_sq"
        );
        assert_eq!(
            acc.state_mean_null_var(),
            &acc.state_mean_null_var[..],
            "state_mean_null_var"
        );
        assert_eq!(
            acc.meas_mean_total(),
            &acc.meas_mean_total[..],
            "meas_mean_total"
        );
        assert_eq!(
            acc.meas_mean_run_sq(),
            &acc.meas_mean_run_sq[..],
            "meas_mean_run_sq"
        );
        assert_eq!(
            acc.meas_comp_total(),
            &acc.meas_comp_total[..],
            "meas_comp_total"
        );
        assert_eq!(
            acc.meas_comp_samples(),
            &acc.meas_comp_samples[..],
            "meas_comp_samples"
        );
        assert_eq!(
            acc.meas_comp_run_sum(),
            &acc.meas_comp_run_sum[..],
            "meas_comp_run_sum"
        );
        assert_eq!(
            acc.meas_comp_run_sq(),
            &acc.meas_comp_run_sq[..],
            "meas_comp_run_sq"
        );
        assert_eq!(
            acc.meas_comp_runs(),
            &acc.meas_comp_runs[..],
            "meas_comp_runs"
        );
        assert_eq!(acc.white_ab(), &acc.white_ab[..], "white_ab");
        assert_eq!(acc.white_a2(), &acc.white_a2[..], "white_a2");
        assert_eq!(acc.white_b2(), &acc.white_b2[..], "white_b2");
        assert_eq!(acc.white_pairs(), &acc.white_pairs[..], "white_pairs");
        assert_eq!(acc.diverged_runs(), acc.diverged_runs, "diverged_runs");
        assert_eq!(
            acc.ill_conditioned_runs(),
            acc.ill_conditioned_runs,
            "ill_conditioned_runs"
        );
        assert_eq!(
            acc.truth_overflow_runs(),
            acc.truth_overflow_runs,
            "truth_overflow_runs"
        );
        assert_eq!(acc.divergences(), &acc.divergences[..], "divergences");
        assert!(acc.runs() > 1 && acc.divergences().len() > 1);
    }

    #[test]
    fn divergence_details_keep_the_first_ten_in_run_order() {
        let mut a = Accumulator::new(1, 1, 1, 0);
        for run in 0..8 {
            a.record_divergence(run, 1, "S".into());
        }
        let mut b = Accumulator::new(1, 1, 1, 0);
        for run in 8..12 {
            b.record_divergence(run, 2, "P".into());
        }
        a.merge(&b);
        assert_eq!(a.diverged_runs, 12);
        let runs: Vec<usize> = a.divergences.iter().map(|d: &Divergence| d.run).collect();
        assert_eq!(runs, (0..10).collect::<Vec<_>>());
    }

    #[test]
    fn the_zero_mean_variance_is_the_run_spread_and_one_run_falls_back_to_the_prediction() {
        // 4 runs whose first-moment sums are 1, 3, −2, 2: total 4, Σ r² = 18, mean 1,
        // s² = (18 − 4)/3 = 14/3, variance N s² = 56/3.
        let mut acc = Accumulator::new(1, 1, 1, 0);
        acc.runs = 4;
        acc.state_mean_total = vec![4.0];
        acc.state_mean_run_sq = vec![18.0];
        acc.meas_mean_total = vec![4.0];
        acc.meas_mean_run_sq = vec![18.0];
        acc.meas_comp_runs = vec![4];
        acc.meas_comp_samples = vec![40.0];
        acc.comp_null_var_runs = 4;
        acc.state_mean_null_var = vec![8.0];
        for v in [acc.state_mean_variance(0), acc.meas_mean_variance(0)] {
            match v {
                SumVariance::RunSpread { var, runs } => {
                    assert!((var - 56.0 / 3.0).abs() < 1e-12, "{var}");
                    assert_eq!(runs, 4);
                }
                other => panic!("{other:?}"),
            }
        }
        // Two runs are the fewest with a spread: per-run sums 1 and 2 (total 3, squares 5)
        // spread s² = 0.5 about their mean, var = N s² = 1.
        let mut two = acc.clone();
        two.runs = 2;
        two.state_mean_total = vec![3.0];
        two.state_mean_run_sq = vec![5.0];
        assert!(
            matches!(two.state_mean_variance(0), SumVariance::RunSpread { var, runs: 2 } if (var - 1.0).abs() < 1e-12),
            "{:?}",
            two.state_mean_variance(0)
        );
        // One run: no spread; the states take the filters' prediction (scaled to the
        // finished runs), the innovations their sample count.
        acc.runs = 1;
        acc.meas_comp_runs = vec![1];
        assert!(
            matches!(acc.state_mean_variance(0), SumVariance::Predicted(v) if (v - 2.0).abs() < 1e-12),
            "{:?}",
            acc.state_mean_variance(0)
        );
        assert!(
            matches!(acc.meas_mean_variance(0), SumVariance::Predicted(v) if v == 40.0),
            "{:?}",
            acc.meas_mean_variance(0)
        );
        // Without error maps one run has nothing to go on; nor has it when no run's null
        // variance was taken (no prediction to scale).
        acc.error_map_missing = 1;
        assert!(matches!(
            acc.state_mean_variance(0),
            SumVariance::Unavailable
        ));
        acc.error_map_missing = 0;
        acc.comp_null_var_runs = 0;
        assert!(
            matches!(acc.state_mean_variance(0), SumVariance::Unavailable),
            "{:?}",
            acc.state_mean_variance(0)
        );
    }
}

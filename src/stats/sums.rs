//! The sufficient statistics of a Monte Carlo evaluation: sums over runs that the engines
//! fill and the report, the objective and the tuner read.

use serde::Serialize;

use super::{SumVariance, Verdict};

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
    pub runs: usize,
    /// Steps per run.
    pub steps: usize,
    /// Largest autocorrelation lag.
    pub lags: usize,
    /// Σ_i NEES_ik.
    pub nees_sum: Vec<f64>,
    /// Σ_i NEES_ik².
    pub nees_sq: Vec<f64>,
    /// Σ_i n_x (degrees of freedom of the step's NEES sum).
    pub nees_dof: Vec<f64>,
    /// Number of runs contributing a NEES at the step.
    pub nees_count: Vec<f64>,
    /// Σ over the runs counted in `null_var_runs` of the variance of the per-run NEES sum
    /// the filter predicts under consistency (see `super::NeesNullVariance`); read it through
    /// [`Accumulator::nees_null_variance`].
    pub nees_null_var: f64,
    /// Runs whose predicted NEES-sum variance is in `nees_null_var`: all of them on the
    /// linear and exact paths, every `NULL_VAR_STRIDE`-th on the generic one
    /// (`crate::montecarlo::NULL_VAR_STRIDE`).
    pub null_var_runs: usize,
    /// Runs sampled for the predicted variance whose filter supplied no error map
    /// (`crate::filter::Estimate::error_map`); when any did, the gate takes the NEES-sum
    /// variance from the spread of the per-run sums instead.
    pub error_map_missing: usize,
    /// Σ over finished runs i of the run's NEES sum `S_i = Σ_k ε_ik`.
    pub nees_run_total: f64,
    /// Σ over finished runs of `S_i²`.
    pub nees_run_total_sq: f64,
    /// Finished runs behind `nees_run_total` (0 on the exact path, which has no runs).
    pub nees_total_runs: usize,
    /// Σ_i NIS_ik.
    pub nis_sum: Vec<f64>,
    /// Σ_i NIS_ik².
    pub nis_sq: Vec<f64>,
    /// Σ_i n_z,ik (the dimension of the measurement each run used at the step).
    pub nis_dof: Vec<f64>,
    /// Number of runs with a measurement at the step.
    pub nis_count: Vec<f64>,
    /// Σ_{i,k} e_j²/P_jj per state component.
    pub state_comp_total: Vec<f64>,
    /// Samples behind `state_comp_total`.
    pub state_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of e_j²/P_jj.
    pub state_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub state_comp_run_sq: Vec<f64>,
    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// of e_j²/P_jj that the filter predicts under consistency (see
    /// `super::ComponentNullVariance`).
    pub state_comp_null_var: Vec<f64>,
    /// Runs whose predicted component variances are in `state_comp_null_var` (computed for
    /// the full gate only, on the same runs as the NEES-sum variance).
    pub comp_null_var_runs: usize,
    /// Σ_{i,k} e_j/√P_jj per state component (n_x): the first moment, 0 in expectation
    /// for a consistent filter. Linear in the data, so a difference of two evaluations with
    /// common random numbers is smooth in a sensor offset.
    pub state_mean_total: Vec<f64>,
    /// Samples behind `state_mean_total`: as `state_comp_samples`, except for records that
    /// give only `e_j²/P_jj` (no sign), which leave it 0 and get no zero-mean test.
    pub state_mean_samples: Vec<f64>,
    /// Σ over finished runs i of the square of the run's own sum `Σ_k e_j/√P_jj` (n_x): the
    /// run-to-run spread, the null variance of `state_mean_total` for a filter that supplies
    /// no error map.
    pub state_mean_run_sq: Vec<f64>,
    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// `Σ_k e_jk/√P_jj,k` that a consistent filter predicts (n_x; see
    /// `super::ComponentNullVariance::mean_variances`).
    pub state_mean_null_var: Vec<f64>,
    /// Σ_{i,k} ν_j/√S_jj per measurement component (n_z). Innovations of a consistent filter
    /// are white, so its null variance is exactly its sample count, `meas_comp_samples`.
    pub meas_mean_total: Vec<f64>,
    /// Σ_{i,k} ν_j²/S_jj per measurement component.
    pub meas_comp_total: Vec<f64>,
    /// Samples behind `meas_comp_total`.
    pub meas_comp_samples: Vec<f64>,
    /// Σ_i of the per-run time average of ν_j²/S_jj.
    pub meas_comp_run_sum: Vec<f64>,
    /// Σ_i of its square.
    pub meas_comp_run_sq: Vec<f64>,
    /// Runs in which the component was measured at least once.
    pub meas_comp_runs: Vec<usize>,
    /// Σ u_k u_{k−l} with u = ν_j/√S_jj.
    pub white_ab: Vec<f64>,
    /// Σ u_k².
    pub white_a2: Vec<f64>,
    /// Σ u_{k−l}².
    pub white_b2: Vec<f64>,
    /// Number of pairs.
    pub white_pairs: Vec<f64>,
    /// Number of runs that stopped early, for any `StopCause`.
    pub diverged_runs: usize,
    /// Of those, the runs stopped by an ill-conditioned covariance.
    pub ill_conditioned_runs: usize,
    /// Of those, the runs stopped by a truth state that overflowed.
    pub truth_overflow_runs: usize,
    /// The first few divergences, by run index.
    pub divergences: Vec<Divergence>,
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
    /// per-run sums.
    pub fn nees_sum_variance(&self) -> SumVariance {
        if self.has_nees_null_variance() {
            SumVariance::Predicted(self.nees_null_variance())
        } else {
            match self.nees_spread_variance() {
                Some((var, runs)) => SumVariance::RunSpread { var, runs },
                None => SumVariance::Unavailable,
            }
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
    /// rests on, by the same policy as [`Self::state_component_variance`]: the filters' own
    /// prediction where every sampled filter supplied its error map, else `N s²` with `s²`
    /// the sample variance of the per-run sums about their mean (about the mean, so that a
    /// bias does not inflate its own yardstick).
    pub fn state_mean_variance(&self, j: usize) -> SumVariance {
        let finished = self.runs.saturating_sub(self.diverged_runs);
        if self.error_map_missing == 0 && self.comp_null_var_runs > 0 {
            let scale = finished as f64 / self.comp_null_var_runs as f64;
            return SumVariance::Predicted(self.state_mean_null_var[j] * scale);
        }
        if finished < 2 {
            return SumVariance::Unavailable;
        }
        let n = finished as f64;
        let mean = self.state_mean_total[j] / n;
        let s2 = ((self.state_mean_run_sq[j] - n * mean * mean) / (n - 1.0)).max(0.0);
        SumVariance::RunSpread {
            var: n * s2,
            runs: finished,
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

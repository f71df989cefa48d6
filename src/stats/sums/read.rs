//! The read side of [`Accumulator`]: one getter per sum, kept apart from the methods that
//! fill and merge them so that the sums' arithmetic reads on one page.

use super::{Accumulator, Divergence};

/// Read access to the sums: the engines fill them through the methods in `mod.rs`, and the
/// statistics read them here.
impl Accumulator {
    /// Runs completed or diverged.
    pub fn runs(&self) -> usize {
        self.runs
    }

    /// Steps per run.
    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Largest autocorrelation lag.
    pub fn lags(&self) -> usize {
        self.lags
    }

    /// Σ_i NEES_ik.
    pub fn nees_sum(&self) -> &[f64] {
        &self.nees_sum
    }

    /// Σ_i NEES_ik².
    pub fn nees_sq(&self) -> &[f64] {
        &self.nees_sq
    }

    /// Σ_i n_x (degrees of freedom of the step's NEES sum).
    pub fn nees_dof(&self) -> &[f64] {
        &self.nees_dof
    }

    /// Number of runs contributing a NEES at the step.
    pub fn nees_count(&self) -> &[f64] {
        &self.nees_count
    }

    /// Σ over the runs counted in `null_var_runs` of the variance of the per-run NEES sum
    /// the filter predicts under consistency (see `super::NeesNullVariance`); read it
    /// through `Accumulator::nees_null_variance`.
    pub fn nees_null_var(&self) -> f64 {
        self.nees_null_var
    }

    /// Runs whose predicted NEES-sum variance is in `nees_null_var`: all of them on the
    /// linear and exact paths, every `NULL_VAR_STRIDE`-th on the generic one
    /// (`crate::montecarlo::NULL_VAR_STRIDE`).
    pub fn null_var_runs(&self) -> usize {
        self.null_var_runs
    }

    /// Runs sampled for the predicted variance whose filter supplied no error map
    /// (`crate::filter::Estimate::error_map`); when any did, the gate takes the NEES-sum
    /// variance from the spread of the per-run sums instead.
    pub fn error_map_missing(&self) -> usize {
        self.error_map_missing
    }

    /// Σ over finished runs i of the run's NEES sum `S_i = Σ_k ε_ik`.
    pub fn nees_run_total(&self) -> f64 {
        self.nees_run_total
    }

    /// Σ over finished runs of `S_i²`.
    pub fn nees_run_total_sq(&self) -> f64 {
        self.nees_run_total_sq
    }

    /// Finished runs behind `nees_run_total` (0 on the exact path, which has no runs).
    pub fn nees_total_runs(&self) -> usize {
        self.nees_total_runs
    }

    /// Σ_i NIS_ik.
    pub fn nis_sum(&self) -> &[f64] {
        &self.nis_sum
    }

    /// Σ_i NIS_ik².
    pub fn nis_sq(&self) -> &[f64] {
        &self.nis_sq
    }

    /// Σ_i n_z,ik (the dimension of the measurement each run used at the step).
    pub fn nis_dof(&self) -> &[f64] {
        &self.nis_dof
    }

    /// Number of runs with a measurement at the step.
    pub fn nis_count(&self) -> &[f64] {
        &self.nis_count
    }

    /// Σ_{i,k} e_j²/P_jj per state component.
    pub fn state_comp_total(&self) -> &[f64] {
        &self.state_comp_total
    }

    /// Samples behind `state_comp_total`.
    pub fn state_comp_samples(&self) -> &[f64] {
        &self.state_comp_samples
    }

    /// Σ_i of the per-run time average of e_j²/P_jj.
    pub fn state_comp_run_sum(&self) -> &[f64] {
        &self.state_comp_run_sum
    }

    /// Σ_i of its square.
    pub fn state_comp_run_sq(&self) -> &[f64] {
        &self.state_comp_run_sq
    }

    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// of e_j²/P_jj that the filter predicts under consistency (see
    /// `super::ComponentNullVariance`).
    pub fn state_comp_null_var(&self) -> &[f64] {
        &self.state_comp_null_var
    }

    /// Runs whose predicted component variances are in `state_comp_null_var` (computed for
    /// the full gate only, on the same runs as the NEES-sum variance).
    pub fn comp_null_var_runs(&self) -> usize {
        self.comp_null_var_runs
    }

    /// Σ_{i,k} e_j/√P_jj per state component (n_x): the first moment, 0 in expectation for
    /// a consistent filter. Linear in the data, so a difference of two evaluations with
    /// common random numbers is smooth in a sensor offset.
    pub fn state_mean_total(&self) -> &[f64] {
        &self.state_mean_total
    }

    /// Samples behind `state_mean_total`: as `state_comp_samples`, except for records that
    /// give only `e_j²/P_jj` (no sign), which leave it 0 and get no zero-mean test.
    pub fn state_mean_samples(&self) -> &[f64] {
        &self.state_mean_samples
    }

    /// Σ over finished runs i of the square of the run's own sum `Σ_k e_j/√P_jj` (n_x): the
    /// run-to-run spread, the null variance of `state_mean_total` for a filter that
    /// supplies no error map.
    pub fn state_mean_run_sq(&self) -> &[f64] {
        &self.state_mean_run_sq
    }

    /// Σ over the runs counted in `comp_null_var_runs` of the variance of the per-run sum
    /// `Σ_k e_jk/√P_jj,k` that a consistent filter predicts (n_x; see
    /// `super::ComponentNullVariance::mean_variances`).
    pub fn state_mean_null_var(&self) -> &[f64] {
        &self.state_mean_null_var
    }

    /// Σ_{i,k} ν_j/√S_jj per measurement component (n_z). Innovations of a consistent
    /// filter are white, so its null variance is exactly its sample count,
    /// `meas_comp_samples`.
    pub fn meas_mean_total(&self) -> &[f64] {
        &self.meas_mean_total
    }

    /// Σ over finished runs i of the square of the run's own sum `Σ_k ν_j/√S_jj` (n_z).
    pub fn meas_mean_run_sq(&self) -> &[f64] {
        &self.meas_mean_run_sq
    }

    /// Σ_{i,k} ν_j²/S_jj per measurement component.
    pub fn meas_comp_total(&self) -> &[f64] {
        &self.meas_comp_total
    }

    /// Samples behind `meas_comp_total`.
    pub fn meas_comp_samples(&self) -> &[f64] {
        &self.meas_comp_samples
    }

    /// Σ_i of the per-run time average of ν_j²/S_jj.
    pub fn meas_comp_run_sum(&self) -> &[f64] {
        &self.meas_comp_run_sum
    }

    /// Σ_i of its square.
    pub fn meas_comp_run_sq(&self) -> &[f64] {
        &self.meas_comp_run_sq
    }

    /// Runs in which the component was measured at least once.
    pub fn meas_comp_runs(&self) -> &[usize] {
        &self.meas_comp_runs
    }

    /// Σ u_k u_{k−l} with u = ν_j/√S_jj.
    pub fn white_ab(&self) -> &[f64] {
        &self.white_ab
    }

    /// Σ u_k².
    pub fn white_a2(&self) -> &[f64] {
        &self.white_a2
    }

    /// Σ u_{k−l}².
    pub fn white_b2(&self) -> &[f64] {
        &self.white_b2
    }

    /// Number of pairs.
    pub fn white_pairs(&self) -> &[f64] {
        &self.white_pairs
    }

    /// Number of runs that stopped early, for any `StopCause`.
    pub fn diverged_runs(&self) -> usize {
        self.diverged_runs
    }

    /// Of those, the runs stopped by an ill-conditioned covariance.
    pub fn ill_conditioned_runs(&self) -> usize {
        self.ill_conditioned_runs
    }

    /// Of those, the runs stopped by a truth state that overflowed.
    pub fn truth_overflow_runs(&self) -> usize {
        self.truth_overflow_runs
    }

    /// The first few divergences, by run index.
    pub fn divergences(&self) -> &[Divergence] {
        &self.divergences
    }
}

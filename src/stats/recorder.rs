//! One run's statistics as it happens, step by step, before they join the sums.

use super::Accumulator;

/// One run's working state for the component and whiteness statistics, which need the
/// run's own sums before they are folded into an [`Accumulator`]: both the generic engine
/// and recorded runs ([`crate::records`]) go through it, so they sum alike.
pub struct RunRecorder {
    n_x: usize,
    n_z: usize,
    lags: usize,
    comp_x: Vec<f64>,
    /// The run's own sums of `e_j/√P_jj`.
    mean_x: Vec<f64>,
    comp_x_n: f64,
    comp_z: Vec<f64>,
    comp_z_n: Vec<f64>,
    /// The last `lags` normalized innovation vectors (NaN where not measured), ring-indexed
    /// by step.
    ring: Vec<f64>,
    /// The current step's normalized innovations.
    u: Vec<f64>,
    /// The current step's `(component, u)`, added to the sums when the step closes.
    pending: Vec<(usize, f64)>,
}

impl RunRecorder {
    /// Working state for n_x state components, n_z measurement components and `lags` lags.
    pub fn new(n_x: usize, n_z: usize, lags: usize) -> Self {
        RunRecorder {
            n_x,
            n_z,
            lags,
            comp_x: vec![0.0; n_x],
            mean_x: vec![0.0; n_x],
            comp_x_n: 0.0,
            comp_z: vec![0.0; n_z],
            comp_z_n: vec![0.0; n_z],
            ring: vec![f64::NAN; lags.max(1) * n_z],
            u: vec![f64::NAN; n_z],
            pending: Vec::new(),
        }
    }

    /// Start a new run.
    pub fn reset(&mut self) {
        self.comp_x.fill(0.0);
        self.mean_x.fill(0.0);
        self.comp_x_n = 0.0;
        self.comp_z.fill(0.0);
        self.comp_z_n.fill(0.0);
        self.ring.fill(f64::NAN);
        self.u.fill(f64::NAN);
        self.pending.clear();
    }

    /// Record one step's normalized state errors `e_j/√P_jj`, in component order (their
    /// squares feed the second-moment sums, the values themselves the zero-mean test).
    pub fn state_step(&mut self, acc: &mut Accumulator, scaled: impl Iterator<Item = f64>) {
        for (j, y) in scaled.enumerate() {
            self.mean_x[j] += y;
            acc.state_mean_total[j] += y;
            acc.state_mean_samples[j] += 1.0;
            self.add_square(acc, j, y * y);
        }
        self.comp_x_n += 1.0;
    }

    /// Record one step's normalized squared state errors `e_j²/P_jj` alone, for records
    /// that give no sign (their state components get no zero-mean test).
    pub fn state_step_squares(&mut self, acc: &mut Accumulator, sq: impl Iterator<Item = f64>) {
        for (j, v) in sq.enumerate() {
            self.add_square(acc, j, v);
        }
        self.comp_x_n += 1.0;
    }

    fn add_square(&mut self, acc: &mut Accumulator, j: usize, v: f64) {
        self.comp_x[j] += v;
        acc.state_comp_total[j] += v;
        acc.state_comp_samples[j] += 1.0;
    }

    /// Record one normalized innovation component `u = ν_j/√S_jj` at the current step.
    pub fn innovation(&mut self, j: usize, u: f64) {
        self.pending.push((j, u));
        self.u[j] = u;
    }

    /// Close step `k` (1-based): add its innovation components, pair its innovations with
    /// earlier steps' and store them for later lags.
    pub fn end_step(&mut self, acc: &mut Accumulator, k: usize) {
        for &(j, u) in &self.pending {
            let v = u * u;
            acc.meas_mean_total[j] += u;
            self.comp_z[j] += v;
            self.comp_z_n[j] += 1.0;
            acc.meas_comp_total[j] += v;
            acc.meas_comp_samples[j] += 1.0;
        }
        self.pending.clear();
        let (m, lags) = (self.n_z, self.lags);
        if lags > 0 {
            for lag in 1..=lags.min(k - 1) {
                let slot = ((k - lag) % lags) * m;
                for j in 0..m {
                    let (a, b) = (self.u[j], self.ring[slot + j]);
                    if a.is_finite() && b.is_finite() {
                        let idx = (lag - 1) * m + j;
                        acc.white_ab[idx] += a * b;
                        acc.white_a2[idx] += a * a;
                        acc.white_b2[idx] += b * b;
                        acc.white_pairs[idx] += 1.0;
                    }
                }
            }
            let slot = (k % lags) * m;
            self.ring[slot..slot + m].copy_from_slice(&self.u);
        }
        self.u.fill(f64::NAN);
    }

    /// Close the run: fold its per-run component averages into the accumulator.
    pub fn end_run(&self, acc: &mut Accumulator) {
        if self.comp_x_n > 0.0 {
            for j in 0..self.n_x {
                acc.add_run_component(true, j, self.comp_x[j] / self.comp_x_n);
                acc.state_mean_run_sq[j] += self.mean_x[j] * self.mean_x[j];
            }
        }
        for j in 0..self.n_z {
            if self.comp_z_n[j] > 0.0 {
                acc.add_run_component(false, j, self.comp_z[j] / self.comp_z_n[j]);
                acc.meas_comp_runs[j] += 1;
            }
        }
        acc.runs += 1;
    }
}

//! One run's statistics as it happens, step by step, before they join the sums.

use super::Accumulator;

/// One run's working state for the component and whiteness statistics: both the generic
/// engine and recorded runs ([`crate::records`]) go through it, so they sum alike.
///
/// Every sum that a run adds to more than once (a component's squares over the steps, the
/// lagged products) is summed over the run here first and joins the [`Accumulator`] once,
/// when the run ends or stops. Each of the accumulator's sums then takes one addend per
/// run, so runs computed side by side and added in run order give the very numbers that
/// runs computed one after the other give (see `crate::montecarlo`).
pub struct RunRecorder {
    n_x: usize,
    n_z: usize,
    lags: usize,
    /// The run's own sums of `e_j²/P_jj`.
    comp_x: Vec<f64>,
    /// The run's own sums of `e_j/√P_jj`.
    mean_x: Vec<f64>,
    comp_x_n: f64,
    /// The run's own sums of `ν_j²/S_jj`.
    comp_z: Vec<f64>,
    /// The run's own sums of `ν_j/√S_jj`.
    mean_z: Vec<f64>,
    comp_z_n: Vec<f64>,
    /// The run's own lagged sums `Σ u_k u_{k−l}`, `Σ u_k²`, `Σ u_{k−l}²`, lag-major as the
    /// accumulator's.
    white_ab: Vec<f64>,
    white_a2: Vec<f64>,
    white_b2: Vec<f64>,
    /// Each component's last `lags` readings, component-major, ring-indexed by the
    /// component's own count of readings: lag l pairs a reading with the l-th reading of
    /// the same component before it, however many steps back (a sensor that reports every
    /// other step, or drops out, pairs with its own previous reading, as `autotune nis`
    /// pairs a field log's).
    history: Vec<f64>,
    /// Each component's readings so far in the run.
    readings: Vec<usize>,
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
            mean_z: vec![0.0; n_z],
            comp_z_n: vec![0.0; n_z],
            white_ab: vec![0.0; lags * n_z],
            white_a2: vec![0.0; lags * n_z],
            white_b2: vec![0.0; lags * n_z],
            history: vec![f64::NAN; lags * n_z],
            readings: vec![0; n_z],
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
        self.mean_z.fill(0.0);
        self.comp_z_n.fill(0.0);
        self.white_ab.fill(0.0);
        self.white_a2.fill(0.0);
        self.white_b2.fill(0.0);
        // A component's history is read only as far as its count of readings reaches.
        self.readings.fill(0);
        self.u.fill(f64::NAN);
        self.pending.clear();
    }

    /// Record one step's normalized state errors `e_j/√P_jj`, in component order (their
    /// squares feed the second-moment sums, the values themselves the zero-mean test).
    pub fn state_step(&mut self, acc: &mut Accumulator, scaled: impl Iterator<Item = f64>) {
        for (j, y) in scaled.enumerate() {
            self.mean_x[j] += y;
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
        acc.state_comp_samples[j] += 1.0;
    }

    /// Record one normalized innovation component `u = ν_j/√S_jj` at the current step.
    pub fn innovation(&mut self, j: usize, u: f64) {
        self.pending.push((j, u));
        self.u[j] = u;
    }

    /// Close the step: add its innovation components, pair each with its own
    /// earlier readings and store it for later lags.
    pub fn end_step(&mut self, acc: &mut Accumulator) {
        for &(j, u) in &self.pending {
            self.mean_z[j] += u;
            self.comp_z[j] += u * u;
            self.comp_z_n[j] += 1.0;
            acc.meas_comp_samples[j] += 1.0;
        }
        let (m, lags) = (self.n_z, self.lags);
        if lags > 0 {
            // Only this step's components pair: a sensor with dozens of components, a few
            // measured a step, costs those few. A component measured twice in the step
            // pairs once, with its last value.
            for (p, &(j, _)) in self.pending.iter().enumerate() {
                if self.pending[p + 1..].iter().any(|&(i, _)| i == j) {
                    continue;
                }
                let (a, seen) = (self.u[j], self.readings[j]);
                let own = &mut self.history[j * lags..(j + 1) * lags];
                for lag in 1..=lags.min(seen) {
                    let b = own[(seen - lag) % lags];
                    if a.is_finite() && b.is_finite() {
                        let idx = (lag - 1) * m + j;
                        self.white_ab[idx] += a * b;
                        self.white_a2[idx] += a * a;
                        self.white_b2[idx] += b * b;
                        acc.white_pairs[idx] += 1.0;
                    }
                }
                own[seen % lags] = a;
                self.readings[j] = seen + 1;
            }
        }
        for &(j, _) in &self.pending {
            self.u[j] = f64::NAN;
        }
        self.pending.clear();
    }

    /// Add the run's own sums to the accumulator's, once per run.
    fn flush(&self, acc: &mut Accumulator) {
        fn add(to: &mut [f64], from: &[f64]) {
            for (a, b) in to.iter_mut().zip(from) {
                *a += b;
            }
        }
        add(&mut acc.state_comp_total, &self.comp_x);
        add(&mut acc.state_mean_total, &self.mean_x);
        add(&mut acc.meas_comp_total, &self.comp_z);
        add(&mut acc.meas_mean_total, &self.mean_z);
        add(&mut acc.white_ab, &self.white_ab);
        add(&mut acc.white_a2, &self.white_a2);
        add(&mut acc.white_b2, &self.white_b2);
    }

    /// Close the run: add its sums and fold its per-run component averages into the
    /// accumulator.
    pub fn end_run(&self, acc: &mut Accumulator) {
        self.flush(acc);
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
                acc.meas_mean_run_sq[j] += self.mean_z[j] * self.mean_z[j];
            }
        }
        acc.runs += 1;
    }

    /// A run that stopped early: the steps it finished still join the sums, but it gives no
    /// per-run averages (the caller records the stop and counts the run).
    pub fn stop_run(&self, acc: &mut Accumulator) {
        self.flush(acc);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic innovation of component j at step k (1-based) of run `run`, NaN
    /// where the component is not measured (component 1 misses steps 4 and 9).
    fn u(run: usize, k: usize, j: usize) -> f64 {
        if j == 1 && (k == 4 || k == 9) {
            f64::NAN
        } else {
            ((k * 7 + j * 3 + run * 11) as f64 * 0.37).sin() * 1.5
        }
    }

    /// By plain loops over `runs` runs of `t` steps of one component's sequence `u(run, k)`
    /// (NaN where unmeasured): `[Σ u_i u_i−lag, Σ u_i², Σ u_i−lag², pairs]` over the
    /// component's own readings i (the measured steps, in step order), each paired with its
    /// lag-th reading before it within the run.
    fn lagged_sums(runs: usize, t: usize, lag: usize, u: impl Fn(usize, usize) -> f64) -> [f64; 4] {
        let mut sums = [0.0; 4];
        for run in 0..runs {
            let own: Vec<f64> = (1..=t).map(|k| u(run, k)).filter(|v| !v.is_nan()).collect();
            for i in lag..own.len() {
                let (a, b) = (own[i], own[i - lag]);
                sums[0] += a * b;
                sums[1] += a * a;
                sums[2] += b * b;
                sums[3] += 1.0;
            }
        }
        sums
    }

    #[test]
    fn sensors_that_take_turns_pair_each_reading_with_their_own_previous_one() {
        // Two sensors that take turns (component 0 at odd steps, 1 at even ones), 10 steps:
        // lag 1 pairs each with its own reading two steps back. Component 0 alternates
        // +1, −1 (ρ₁ = −1), component 1 repeats 2 (ρ₁ = +1); each has 5 readings, so 4 pairs
        // at lag 1 and 3 at lag 2, and none across the run boundary.
        let mut acc = Accumulator::new(10, 0, 2, 2);
        let mut rec = RunRecorder::new(0, 2, 2);
        for _ in 0..2 {
            rec.reset();
            for k in 1..=10usize {
                if k % 2 == 1 {
                    rec.innovation(0, if k % 4 == 1 { 1.0 } else { -1.0 });
                } else {
                    rec.innovation(1, 2.0);
                }
                rec.end_step(&mut acc);
            }
            rec.end_run(&mut acc);
        }
        assert_eq!(acc.white_pairs, vec![8.0, 8.0, 6.0, 6.0]);
        assert_eq!(acc.white_ab, vec![-8.0, 32.0, 6.0, 24.0]);
        assert_eq!(acc.white_a2, vec![8.0, 32.0, 6.0, 24.0]);
        assert_eq!(acc.white_b2, vec![8.0, 32.0, 6.0, 24.0]);
    }

    #[test]
    fn lagged_products_match_a_brute_force_sum_over_every_lag_up_to_l() {
        // Two runs of T = 12 steps, two components (the second missing two steps), L = 3
        // lags: the recorder's sums of u_i u_{i−l}, u_i², u_{i−l}² and the pair counts
        // against plain loops over each component's own readings. Tolerance 1e-12: a few
        // dozen rounded products.
        let (t, m, lags) = (12, 2, 3);
        let mut acc = Accumulator::new(t, 0, m, lags);
        let mut rec = RunRecorder::new(0, m, lags);
        for run in 0..2 {
            rec.reset();
            for k in 1..=t {
                for j in 0..m {
                    if u(run, k, j).is_finite() {
                        rec.innovation(j, u(run, k, j));
                    }
                }
                rec.end_step(&mut acc);
            }
            rec.end_run(&mut acc);
        }
        for lag in 1..=lags {
            for j in 0..m {
                let [ab, a2, b2, pairs] = lagged_sums(2, t, lag, |run, k| u(run, k, j));
                let idx = (lag - 1) * m + j;
                let what = format!("lag {lag} of {lags}, component {j}");
                assert_eq!(acc.white_pairs[idx], pairs, "{what}: pairs");
                assert!(
                    (acc.white_ab[idx] - ab).abs() < 1e-12,
                    "{what}: Σ u_k u_k−l"
                );
                assert!((acc.white_a2[idx] - a2).abs() < 1e-12, "{what}: Σ u_k²");
                assert!((acc.white_b2[idx] - b2).abs() < 1e-12, "{what}: Σ u_k−l²");
            }
        }
        // Component 1 is measured at 10 of the 12 steps of each run.
        assert_eq!(acc.meas_comp_samples, vec![24.0, 20.0]);
        assert_eq!(acc.meas_comp_runs, vec![2, 2]);
        assert_eq!(acc.runs, 2);
    }

    // The step and component indices are the sums' own subscripts.
    #[allow(clippy::needless_range_loop)]
    #[test]
    fn a_step_pairs_only_its_own_components_and_a_repeated_one_once_with_its_last_value() {
        // Four components, two lags, eight steps; each step measures a few of them, and
        // component 2 twice at steps 3 and 6 (values v, then v + 1). The lagged sums must be
        // those of the sequence of each step's last values (NaN where unmeasured), and the
        // second-moment sums must count both values. Exact: each sum adds the same products
        // in the same order.
        let (t, m, lags) = (8, 4, 2);
        let measured = |k: usize, j: usize| !(k + j).is_multiple_of(3) || j == 2;
        let value = |k: usize, j: usize| (k * 5 + j) as f64 * 0.25 - 2.0;
        let mut acc = Accumulator::new(t, 0, m, lags);
        let mut rec = RunRecorder::new(0, m, lags);
        rec.reset();
        let mut last = vec![vec![f64::NAN; m]; t + 1];
        let mut samples = vec![0.0; m];
        for k in 1..=t {
            for j in (0..m).rev() {
                if measured(k, j) {
                    rec.innovation(j, value(k, j));
                    last[k][j] = value(k, j);
                    samples[j] += 1.0;
                }
            }
            if k == 3 || k == 6 {
                rec.innovation(2, value(k, 2) + 1.0);
                last[k][2] = value(k, 2) + 1.0;
                samples[2] += 1.0;
            }
            rec.end_step(&mut acc);
        }
        rec.end_run(&mut acc);
        for lag in 1..=lags {
            for j in 0..m {
                let [ab, a2, b2, pairs] = lagged_sums(1, t, lag, |_, k| last[k][j]);
                let idx = (lag - 1) * m + j;
                let what = format!("lag {lag}, component {j}");
                assert_eq!(acc.white_pairs[idx], pairs, "{what}: pairs");
                assert_eq!(acc.white_ab[idx], ab, "{what}: Σ u_k u_k−l");
                assert_eq!(acc.white_a2[idx], a2, "{what}: Σ u_k²");
                assert_eq!(acc.white_b2[idx], b2, "{what}: Σ u_k−l²");
            }
        }
        assert_eq!(acc.meas_comp_samples, samples);
        assert_eq!(samples[2], 10.0);
    }

    #[test]
    fn component_sums_and_per_run_averages_match_the_sequences() {
        // One state component over two runs of three steps: e/√P = (1, −2, 3) and
        // (0.5, 0.5, −1); one measurement component measured at steps 1 and 3 only.
        let mut acc = Accumulator::new(3, 1, 1, 0);
        let mut rec = RunRecorder::new(1, 1, 0);
        let runs = [[1.0, -2.0, 3.0], [0.5, 0.5, -1.0]];
        for ys in runs {
            rec.reset();
            for (k, y) in ys.iter().enumerate() {
                rec.state_step(&mut acc, std::iter::once(*y));
                if k != 1 {
                    rec.innovation(0, 2.0 * y);
                }
                rec.end_step(&mut acc);
            }
            rec.end_run(&mut acc);
        }
        // Squares: run 1 sums 14 (average 14/3), run 2 sums 1.5 (average 0.5).
        assert_eq!(acc.state_comp_total, vec![15.5]);
        assert_eq!(acc.state_comp_samples, vec![6.0]);
        assert_eq!(acc.state_mean_total, vec![2.0]);
        assert_eq!(acc.state_mean_samples, vec![6.0]);
        assert!((acc.state_comp_run_sum[0] - (14.0 / 3.0 + 0.5)).abs() < 1e-12);
        assert!((acc.state_comp_run_sq[0] - ((14.0f64 / 3.0).powi(2) + 0.25)).abs() < 1e-12);
        // Per-run sums of e/√P: 2 and 0.
        assert_eq!(acc.state_mean_run_sq, vec![4.0]);
        // Innovations 2y at steps 1 and 3: (2, 6) and (1, −2).
        assert_eq!(acc.meas_mean_total, vec![7.0]);
        // Per-run sums of ν/√S: 8 and −1.
        assert_eq!(acc.meas_mean_run_sq, vec![65.0]);
        assert_eq!(acc.meas_comp_total, vec![45.0]);
        assert_eq!(acc.meas_comp_samples, vec![4.0]);
        assert!((acc.meas_comp_run_sum[0] - (20.0 + 2.5)).abs() < 1e-12);
        assert!((acc.meas_comp_run_sq[0] - (400.0 + 6.25)).abs() < 1e-12);
        assert_eq!((acc.meas_comp_runs[0], acc.runs), (2, 2));
    }

    #[test]
    fn a_stopped_runs_finished_steps_join_the_sums_without_its_averages() {
        // Two steps of e/√P = 1, −2 and ν/√S = 3, then the run stops: the sums hold those
        // steps (once), and the per-run averages and run counts do not (the caller counts a
        // stopped run). A finished run after it adds to them as usual.
        let mut acc = Accumulator::new(4, 1, 1, 1);
        let mut rec = RunRecorder::new(1, 1, 1);
        rec.reset();
        for y in [1.0, -2.0] {
            rec.innovation(0, 3.0 * y);
            rec.end_step(&mut acc);
            rec.state_step(&mut acc, std::iter::once(y));
        }
        rec.stop_run(&mut acc);
        assert_eq!(acc.state_comp_total, vec![5.0]);
        assert_eq!(acc.state_mean_total, vec![-1.0]);
        assert_eq!(acc.meas_comp_total, vec![45.0]);
        assert_eq!(acc.meas_mean_total, vec![-3.0]);
        assert_eq!(acc.white_ab, vec![-18.0]);
        assert_eq!((acc.white_a2[0], acc.white_b2[0]), (36.0, 9.0));
        assert_eq!(acc.state_comp_run_sum, vec![0.0]);
        assert_eq!(acc.meas_comp_runs, vec![0]);
        assert_eq!(acc.runs, 0);
        rec.reset();
        rec.state_step(&mut acc, std::iter::once(2.0));
        rec.end_step(&mut acc);
        rec.end_run(&mut acc);
        assert_eq!(acc.state_comp_total, vec![9.0]);
        assert_eq!(acc.state_comp_run_sum, vec![4.0]);
        assert_eq!(acc.runs, 1);
    }
}

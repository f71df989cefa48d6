//! After the search: the gate's own deviates and their sensitivity to the parameters, a
//! final refinement on more runs, the confirmation on fresh seeds, and how precisely the
//! gate's data pin each parameter down.
//!
//! The search minimizes J on common random numbers, so its optimum carries the noise of the
//! search runs; and J weighs the statistics by fixed weights, not by how sharply the gate
//! tests them. A tuned filter that is to pass the gate at its nominal rate on fresh seeds
//! must sit where every gate test's deviate z (see [`gate_deviates`]) is near 0, with an
//! error small against the deviates' own spread at the problem's N. So:
//!
//! - **Sensitivity**: `D = ∂z/∂y` at the search's optimum by forward differences (a 5%
//!   step in each log-parameter) on the search's runs. A deviate of a fixed relative error
//!   grows as the square root of the runs, so `D` scales to any run count by `√(R/R_D)`.
//! - **Refinement** (Monte Carlo scoring): Levenberg–Marquardt steps on `|z|²` evaluated on
//!   four times the search's runs (same seed: the search's runs and more), with `D` scaled
//!   to them; each step costs one evaluation, and one that would move the deviates at N by
//!   less than a quarter of their standard deviation ([`MIN_MOVE`]) is not taken. Its error
//!   in z units is half the search's.
//! - **Confirmation**: the gate at the problem's N on K fresh seeds, reported as a count
//!   against the binomial band of a consistent filter (which passes each with probability
//!   at least 1 − α).
//! - **Resolution**: the sandwich covariance of the estimate the gate's N runs would give,
//!   `Var(ŷ) = A⁻¹ D_N' Σ D_N A⁻¹` with `A = D_N' D_N` and Σ the covariance of the
//!   deviates over the confirmation seeds: Monte Carlo noise only, so a structural misfit
//!   (deviates far from 0 on every seed) does not pass for noise.

use nalgebra::{DMatrix, DVector, SymmetricEigen};
use rayon::prelude::*;

use super::cost::Cost;
use super::result::{Confirmation, Resolution};
use crate::check::{Truth, band_low, judge};
use crate::experiment::Experiment;
use crate::montecarlo::McConfig;
use crate::rng::seed_at;
use crate::stats::{ConsistencyReport, gate_deviates};

/// Forward-difference step of the sensitivity, log units (5%).
const STEP: f64 = 0.05;
/// A parameter that the gate's data leave free by more than this factor is not
/// identifiable.
const MAX_FACTOR: f64 = 2.0;
/// Levenberg–Marquardt steps of the refinement.
const REFINE_STEPS: usize = 4;
/// A refinement step that would move the gate's deviates at its N by less than this (the
/// norm of the predicted change, in the deviates' standard deviations) is not taken.
const MIN_MOVE: f64 = 0.25;

/// The gate run at one parameter point.
pub(super) struct Gate<'a> {
    model: &'a dyn Experiment,
    /// Where the experiment's own failures are kept.
    cost: &'a Cost<'a>,
    /// The problem's Monte Carlo settings (N, gate, α).
    mc: McConfig,
    use_nees: bool,
    /// Only one decoupled block's deviates: its state and measurement components.
    block: Option<(Vec<usize>, Vec<usize>)>,
}

impl<'a> Gate<'a> {
    pub(super) fn new(
        model: &'a dyn Experiment,
        cost: &'a Cost<'a>,
        mc: McConfig,
        use_nees: bool,
    ) -> Self {
        Gate {
            model,
            cost,
            mc,
            use_nees,
            block: None,
        }
    }

    /// This gate's deviates restricted to one decoupled block (its state components
    /// `states` and measurement components `measurements`): the block's per-component
    /// tests and its measurements' whiteness, so that refining the block's parameters
    /// answers to the block's own evidence and never to another block's misfit through the
    /// pooled time averages.
    pub(super) fn for_block(mut self, states: &[usize], measurements: &[usize]) -> Self {
        self.block = Some((states.to_vec(), measurements.to_vec()));
        self
    }

    /// The gate's report at `theta` on `runs` runs from `seed`.
    pub(super) fn report(&self, theta: &[f64], runs: usize, seed: u64) -> ConsistencyReport {
        let mc = self.mc.with_runs(runs).unwrap_or(self.mc).with_seed(seed);
        judge(
            self.model,
            &self.cost.monte_carlo(theta, &mc),
            &mc,
            Truth::from_use_nees(self.use_nees),
        )
    }

    /// The gate's deviates at `theta`, `None` if the filter diverged.
    fn deviates(&self, theta: &[f64], runs: usize, seed: u64) -> Option<DVector<f64>> {
        let r = self.report(theta, runs, seed);
        let z = match &self.block {
            None => gate_deviates(&r),
            Some((states, meas)) => block_deviates(&r, states, meas),
        };
        (r.diverged_runs == 0)
            .then(|| DVector::from_vec(z))
            .filter(|z| z.iter().all(|v| v.is_finite()))
    }
}

/// One block's deviates in `report`, scaled as [`gate_deviates`] scales its own: each
/// component's ratio as a multiple of its interval's half-width (at the gate's statistic
/// quantile), and each of the block's measurements' autocorrelations times √pairs.
fn block_deviates(report: &ConsistencyReport, states: &[usize], meas: &[usize]) -> Vec<f64> {
    let z = crate::stats::normal_two_sided_quantile(report.statistic_alpha);
    let mut out = Vec::new();
    let picked = states
        .iter()
        .filter_map(|&j| report.state_components.get(j))
        .chain(
            meas.iter()
                .filter_map(|&j| report.measurement_components.get(j)),
        );
    for c in picked {
        let half = if c.value >= 1.0 {
            c.interval.upper - 1.0
        } else {
            1.0 - c.interval.lower
        };
        if c.samples > 0.0 && c.interval.lower.is_finite() && half > 0.0 && c.value.is_finite() {
            out.push(z * (c.value - 1.0) / half);
        }
    }
    let names: Vec<&str> = meas
        .iter()
        .filter_map(|&j| report.measurement_components.get(j))
        .map(|c| c.name.as_str())
        .collect();
    out.extend(
        report
            .whiteness
            .iter()
            .filter(|w| names.contains(&w.component.as_str()))
            .map(|w| w.pairs.sqrt() * w.rho),
    );
    out
}

/// The sensitivity `D = ∂z/∂y` at `y` on `runs` runs from `seed`, with the deviates there;
/// `None` if any evaluation diverged or the deviates changed shape. Costs d + 1 runs.
pub(super) fn sensitivity(
    gate: &Gate<'_>,
    cost: &Cost<'_>,
    y: &[f64],
    runs: usize,
    seed: u64,
) -> Option<(DVector<f64>, DMatrix<f64>)> {
    let z0 = gate.deviates(&cost.theta(y), runs, seed)?;
    let mut d = DMatrix::zeros(z0.len(), y.len());
    for k in 0..y.len() {
        // Step inwards at the upper bound, so the difference stays inside the box.
        let h = if y[k] + STEP > cost.hi[k] {
            -STEP
        } else {
            STEP
        };
        let mut yk = y.to_vec();
        yk[k] += h;
        let zk = gate.deviates(&cost.theta(&yk), runs, seed)?;
        if zk.len() != z0.len() {
            return None;
        }
        d.set_column(k, &((zk - &z0) / h));
    }
    Some((z0, d))
}

/// The refinement: Levenberg–Marquardt on `|z|²` at `runs` runs from `seed`, from `y`,
/// with the fixed sensitivity `d` (already scaled to `runs`). Returns the best point and
/// the evaluations spent.
pub(super) fn refine(
    gate: &Gate<'_>,
    cost: &Cost<'_>,
    y: &[f64],
    d: &DMatrix<f64>,
    runs: usize,
    seed: u64,
) -> (Vec<f64>, usize) {
    let mut evals = 1;
    let Some(mut z) = gate.deviates(&cost.theta(y), runs, seed) else {
        return (y.to_vec(), evals);
    };
    if z.len() != d.nrows() {
        return (y.to_vec(), evals);
    }
    let mut best = y.to_vec();
    let mut lambda = 1e-3;
    let a = d.transpose() * d;
    let scale = DVector::from_iterator(a.nrows(), (0..a.nrows()).map(|i| a[(i, i)].max(1e-12)));
    while evals <= REFINE_STEPS {
        let g = d.transpose() * &z;
        let mut m = a.clone();
        for i in 0..m.nrows() {
            m[(i, i)] += lambda * scale[i];
        }
        let Some(step) = m.cholesky().map(|c| -c.solve(&g)) else {
            break;
        };
        if step.amax() < 1e-3 {
            break;
        }
        if too_small_a_step(d, &step, runs, gate.mc.runs()) {
            break;
        }
        let trial = cost.clamp(
            &best
                .iter()
                .zip(step.iter())
                .map(|(a, b)| a + b)
                .collect::<Vec<_>>(),
        );
        evals += 1;
        match gate.deviates(&cost.theta(&trial), runs, seed) {
            Some(zt) if zt.len() == z.len() && zt.norm_squared() < z.norm_squared() => {
                best = trial;
                z = zt;
                lambda = (lambda / 10.0).max(1e-6);
            }
            _ => lambda *= 10.0,
        }
    }
    (best, evals)
}

/// Whether `step` would move the gate's deviates at its N (`gate_runs`) by less than
/// [`MIN_MOVE`] of their standard deviations (the norm of the predicted change), by the
/// sensitivity `d` scaled to the refinement's `runs`: then no outcome of the gate on fresh
/// seeds changes enough to pay for an evaluation on the refinement's runs.
fn too_small_a_step(d: &DMatrix<f64>, step: &DVector<f64>, runs: usize, gate_runs: usize) -> bool {
    let at_n = (d * step).norm() / (runs as f64 / gate_runs as f64).sqrt();
    at_n < MIN_MOVE
}

/// The confirmation: the gate at `theta` on `seeds` fresh seeds from `first` at the
/// problem's N, or once when the experiment is `recorded` data. Returns the count, the
/// first seed's report, and each seed's deviates.
pub(super) fn confirm(
    gate: &Gate<'_>,
    theta: &[f64],
    first: u64,
    seeds: usize,
    recorded: bool,
) -> (Confirmation, ConsistencyReport, Vec<DVector<f64>>) {
    let seeds = if recorded { 1 } else { seeds };
    let n = gate.mc.runs();
    let mut passed = 0;
    let mut deviates = Vec::with_capacity(seeds);
    let mut first_report = None;
    // The seeds side by side: a seed's N runs are often fewer chunks than there are
    // threads (60 runs are one chunk), and the reports come back in seed order.
    let reports: Vec<ConsistencyReport> = (0..seeds)
        .into_par_iter()
        .map(|k| gate.report(theta, n, seed_at(first, k)))
        .collect();
    for r in reports {
        passed += usize::from(r.verdict.passes());
        if r.diverged_runs == 0 {
            deviates.push(DVector::from_vec(gate_deviates(&r)));
        }
        if first_report.is_none() {
            first_report = Some(r);
        }
    }
    let confirmation = Confirmation {
        first_seed: first,
        seeds,
        passed,
        band_low: if recorded {
            1
        } else {
            band_low(seeds, gate.mc.alpha())
        },
        recorded,
    };
    let report = first_report.unwrap_or_else(|| gate.report(theta, n, first));
    (confirmation, report, deviates)
}

/// Per-parameter search-bound flags without a resolution factor: for one recorded data set,
/// where there is no seed-to-seed spread to measure precision by, but a value on its bound
/// still says the data may want it beyond.
pub(super) fn bounds_only(cost: &Cost<'_>, y: &[f64], fixed: &[bool]) -> Vec<Resolution> {
    let mut k = 0;
    fixed
        .iter()
        .map(|&fx| {
            if fx {
                return Resolution::FIXED;
            }
            let at_bound = cost.near_bound(k, y);
            k += 1;
            Resolution {
                factor: None,
                identifiable: !at_bound,
                at_bound,
            }
        })
        .collect()
}

/// Per-parameter resolution from the sandwich covariance (module documentation) of the
/// free parameters at `y`: `d_n` the sensitivity scaled to the gate's N, `deviates` the
/// confirmation seeds' deviates; `fixed` flags every parameter in problem order.
pub(super) fn resolution(
    cost: &Cost<'_>,
    y: &[f64],
    d_n: &DMatrix<f64>,
    deviates: &[DVector<f64>],
    fixed: &[bool],
) -> Vec<Resolution> {
    let var = sandwich(d_n, deviates);
    let twins = twins(d_n, cost, y);
    let mut out = Vec::with_capacity(fixed.len());
    let mut k = 0;
    for &fx in fixed {
        if fx {
            out.push(Resolution::FIXED);
            continue;
        }
        // Two standard deviations either way: the factor within which the gate's N runs
        // determine the parameter with about 95% confidence.
        let factor = if twins[k] {
            f64::INFINITY
        } else {
            (2.0 * var[k].sqrt()).exp()
        };
        let at_bound = cost.near_bound(k, y);
        out.push(Resolution {
            factor: Some(factor),
            identifiable: factor.is_finite() && factor <= MAX_FACTOR && !at_bound,
            at_bound,
        });
        k += 1;
    }
    out
}

/// Parameters that enter the statistics only together with another one: their
/// sensitivities per unit of parameter (not of its logarithm) are parallel (cosine above
/// `1 − 1e-4`), as for two variances that add. Locally one of them may look determined
/// (when the other is tiny, its log-sensitivity is too), but along the valley any split of
/// their sum fits, so neither is.
fn twins(d: &DMatrix<f64>, cost: &Cost<'_>, y: &[f64]) -> Vec<bool> {
    let p = d.ncols();
    let theta: Vec<f64> = y
        .iter()
        .enumerate()
        .map(|(k, v)| v.clamp(cost.lo[k], cost.hi[k]).exp())
        .collect();
    let cols: Vec<DVector<f64>> = (0..p).map(|k| d.column(k) / theta[k]).collect();
    let mut out = vec![false; p];
    for i in 0..p {
        for j in 0..i {
            let (ni, nj) = (cols[i].norm(), cols[j].norm());
            if ni > 0.0 && nj > 0.0 && (cols[i].dot(&cols[j]) / (ni * nj)).abs() > 1.0 - 1e-4 {
                out[i] = true;
                out[j] = true;
            }
        }
    }
    out
}

/// The diagonal of `A⁻¹ D' Σ D A⁻¹`, `A = D'D`. A direction the deviates do not depend
/// on (an eigenvalue of A below 1e-10 of the largest) cannot be determined by any data: its
/// parameters get an infinite variance.
fn sandwich(d: &DMatrix<f64>, deviates: &[DVector<f64>]) -> Vec<f64> {
    let p = d.ncols();
    let eig = SymmetricEigen::new(d.transpose() * d);
    let lmax = eig.eigenvalues.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    let flat: Vec<usize> = (0..p)
        .filter(|&k| {
            eig.eigenvalues[k].is_nan() || eig.eigenvalues[k] <= 1e-10 * lmax || lmax == 0.0
        })
        .collect();
    // A⁻¹ on the determined directions.
    let mut a_inv = DMatrix::zeros(p, p);
    for k in (0..p).filter(|k| !flat.contains(k)) {
        let v = eig.eigenvectors.column(k);
        a_inv += (v * v.transpose()) / eig.eigenvalues[k];
    }
    // D' Σ D from the projected deviates of the seeds (the covariance of m deviates from
    // K seeds is rank K at most, but only its d × d projection is needed).
    let mut b = DMatrix::zeros(p, p);
    if deviates.len() > 1 && deviates.iter().all(|z| z.len() == d.nrows()) {
        let proj: Vec<DVector<f64>> = deviates.iter().map(|z| d.transpose() * z).collect();
        let mean = proj.iter().fold(DVector::zeros(p), |a, v| a + v) / proj.len() as f64;
        for v in &proj {
            let c = v - &mean;
            b += &c * c.transpose();
        }
        b /= (proj.len() - 1) as f64;
    }
    let var = &a_inv * b * &a_inv;
    (0..p)
        .map(|i| {
            let loose = flat.iter().any(|&k| eig.eigenvectors[(i, k)].abs() > 1e-3);
            if loose {
                f64::INFINITY
            } else {
                var[(i, i)].max(0.0)
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sandwich_of_a_linear_model_is_its_least_squares_covariance() {
        // z = D y + e with e ~ N(0, I): the least-squares estimate has covariance
        // (D'D)⁻¹. Deviates of the exact covariance's square root columns (± pairs)
        // reproduce Σ = I exactly in the sample covariance.
        let d = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 0.0, 2.0, 1.0, 1.0]);
        let mut zs = Vec::new();
        for i in 0..3 {
            let mut e = DVector::zeros(3);
            e[i] = 1.0;
            zs.push(e.clone());
            zs.push(-e);
        }
        // Sample covariance over 6 draws with mean 0: Σ e e' / 5 = 2 I / 5.
        let var = sandwich(&d, &zs);
        let a_inv = (d.transpose() * &d).try_inverse().unwrap();
        for (i, v) in var.iter().enumerate() {
            let want = 0.4 * a_inv[(i, i)];
            assert!((v - want).abs() < 1e-12, "{i}: {v} vs {want}");
        }
        // A parameter the deviates do not depend on is free.
        let flat = DMatrix::from_row_slice(3, 2, &[1.0, 0.0, 2.0, 0.0, 1.0, 0.0]);
        let var = sandwich(&flat, &zs);
        assert!(var[0].is_finite() && var[1].is_infinite(), "{var:?}");
    }
}

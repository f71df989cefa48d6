//! A step's expected values, and the moments of a Gaussian quadratic form they are made of.

#![allow(non_snake_case)]

use nalgebra::{DMatrix, DVector};

use crate::montecarlo::truth_moments::STEADY_RTOL;
use crate::stats::Accumulator;

/// `E[x' M⁻¹ x]` and `E[(x' M⁻¹ x)²]` for x ~ N(μ, Σ), given `M⁻¹` (symmetric):
/// `tr B + μ'M⁻¹μ` and `(tr B)² + 2 tr(B²) + 4 μ' M⁻¹ Σ M⁻¹ μ + 2 tr(B) μ'M⁻¹μ + (μ'M⁻¹μ)²`,
/// `B = M⁻¹ Σ`, in plain loops (a few states: no packing), in the storage of `scratch`.
pub(super) fn gaussian_quadratic_moments(
    minv: &DMatrix<f64>,
    sigma: &DMatrix<f64>,
    mu: &DVector<f64>,
    scratch: &mut QuadScratch,
) -> (f64, f64) {
    let n = mu.len();
    let (w, s) = (minv.as_slice(), sigma.as_slice());
    let QuadScratch {
        b,
        minv_mu,
        s_minv_mu,
    } = scratch;
    b.clear();
    b.resize(n * n, 0.0);
    for j in 0..n {
        let col = &mut b[j * n..(j + 1) * n];
        for k in 0..n {
            let skj = s[k + j * n];
            for (bi, wi) in col.iter_mut().zip(&w[k * n..(k + 1) * n]) {
                *bi += wi * skj;
            }
        }
    }
    let tr: f64 = (0..n).map(|i| b[i + i * n]).sum();
    let mut tr2 = 0.0;
    for j in 0..n {
        for i in 0..n {
            tr2 += b[i + j * n] * b[j + i * n];
        }
    }
    sized(minv_mu, n);
    minv.mul_to(mu, minv_mu);
    let q = mu.dot(minv_mu);
    sized(s_minv_mu, n);
    sigma.mul_to(minv_mu, s_minv_mu);
    let cross = minv_mu.dot(s_minv_mu);
    (
        tr + q,
        tr * tr + 2.0 * tr2 + 4.0 * cross + 2.0 * tr * q + q * q,
    )
}

/// The storage [`gaussian_quadratic_moments`] works in: `B`, `M⁻¹ μ` and `Σ M⁻¹ μ`.
#[derive(Default)]
pub(super) struct QuadScratch {
    b: Vec<f64>,
    minv_mu: DVector<f64>,
    s_minv_mu: DVector<f64>,
}

/// The expected per-run values of one step.
#[derive(Default)]
pub(super) struct StepValues {
    pub(super) nees: f64,
    pub(super) nees_sq: f64,
    pub(super) nis: f64,
    pub(super) nis_sq: f64,
    pub(super) comp_x: Vec<f64>,
    pub(super) comp_z: Vec<f64>,
    /// `E[e_j]/√P_jj`.
    pub(super) mean_x: Vec<f64>,
    /// `E[ν_j]/√S_jj`.
    pub(super) mean_z: Vec<f64>,
    /// The lags with a step behind them (up to the configured lags).
    pub(super) lags: usize,
    /// `white[(l − 1) m + j]` = E[u_k,j u_{k−l},j].
    pub(super) white: Vec<f64>,
    /// `lagged_b2[(l − 1) m + j]` = E[u_{k−l},j²].
    pub(super) lagged_b2: Vec<f64>,
}

impl StepValues {
    /// Whether every value equals `o`'s to [`STEADY_RTOL`] relative.
    pub(super) fn same_as(&self, o: &StepValues) -> bool {
        let close = |a: f64, b: f64| {
            (a - b).abs() <= STEADY_RTOL * a.abs().max(b.abs()).max(f64::MIN_POSITIVE)
        };
        let all = |a: &[f64], b: &[f64]| {
            a.len() == b.len() && a.iter().zip(b).all(|(x, y)| close(*x, *y))
        };
        // A mean in standard deviations decays geometrically towards 0 and never settles
        // relative to itself; 1e-12 σ is settled enough.
        let near = |a: &[f64], b: &[f64]| {
            a.len() == b.len()
                && a.iter()
                    .zip(b)
                    .all(|(x, y)| (x - y).abs() <= STEADY_RTOL * x.abs().max(y.abs()).max(1.0))
        };
        close(self.nees, o.nees)
            && close(self.nees_sq, o.nees_sq)
            && close(self.nis, o.nis)
            && close(self.nis_sq, o.nis_sq)
            && all(&self.comp_x, &o.comp_x)
            && all(&self.comp_z, &o.comp_z)
            && near(&self.mean_x, &o.mean_x)
            && near(&self.mean_z, &o.mean_z)
            && self.lags == o.lags
            && all(&self.white, &o.white)
            && all(&self.lagged_b2, &o.lagged_b2)
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn add(
        &self,
        acc: &mut Accumulator,
        i: usize,
        runs: f64,
        n: usize,
        m: usize,
        comp_x: &mut [f64],
        comp_z: &mut [f64],
        lags: usize,
        k: usize,
    ) {
        acc.nees_sum[i] = runs * self.nees;
        acc.nees_sq[i] = runs * self.nees_sq;
        acc.nees_dof[i] = runs * n as f64;
        acc.nees_count[i] = runs;
        acc.nis_sum[i] = runs * self.nis;
        acc.nis_sq[i] = runs * self.nis_sq;
        acc.nis_dof[i] = runs * m as f64;
        acc.nis_count[i] = runs;
        for (j, (c, v)) in comp_x.iter_mut().zip(&self.comp_x).enumerate() {
            *c += v;
            acc.state_comp_total[j] += runs * v;
            acc.state_comp_samples[j] += runs;
            acc.state_mean_total[j] += runs * self.mean_x[j];
            acc.state_mean_samples[j] += runs;
        }
        for (j, (c, v)) in comp_z.iter_mut().zip(&self.comp_z).enumerate() {
            *c += v;
            acc.meas_comp_total[j] += runs * v;
            acc.meas_comp_samples[j] += runs;
            acc.meas_mean_total[j] += runs * self.mean_z[j];
        }
        for lag in 1..=lags.min(k - 1).min(self.lags) {
            for j in 0..m {
                let o = (lag - 1) * m + j;
                acc.white_ab[o] += runs * self.white[o];
                acc.white_a2[o] += runs * self.comp_z[j];
                acc.white_b2[o] += runs * self.lagged_b2[o];
                acc.white_pairs[o] += runs;
            }
        }
    }
}

/// `v` of length `n`, its storage kept where it has that length already (the contents
/// are written over by the caller).
pub(super) fn sized(v: &mut DVector<f64>, n: usize) {
    if v.len() != n {
        *v = DVector::zeros(n);
    }
}

//! The variance of one run's NEES sum that a consistent filter predicts for itself.

use nalgebra::{Cholesky, DMatrix, Dyn};

/// Streaming computation of the variance of one run's NEES sum `Σ_k ε_k` that a filter
/// predicts for itself if it is consistent.
///
/// Under consistency `e_k = A_k e_{k−1} + (noise independent of e_{k−1})`, so
/// `E[e_k e_j'] = Φ_kj P_j` with `Φ_kj = A_k ⋯ A_{j+1}`, and for jointly Gaussian errors
/// `Cov(ε_j, ε_k) = 2 tr(P_k⁻¹ Φ_kj P_j Φ_kj')`. Summing over `j < k` gives
/// `2 tr(P_k⁻¹ G_k)` with `G_k = A_k (G_{k−1} + P_{k−1}) A_k'`, `G_1 = 0`, hence
/// `Var(Σ_k ε_k) = Σ_k [2 n_x + 4 tr(P_k⁻¹ G_k)]`, in O(n³) per step.
#[derive(Debug, Clone)]
pub struct NeesNullVariance {
    n: usize,
    g: DMatrix<f64>,
    p_prev: Option<DMatrix<f64>>,
    var: f64,
}

impl NeesNullVariance {
    /// Start a run with state dimension `n`.
    pub fn new(n: usize) -> Self {
        NeesNullVariance {
            n,
            g: DMatrix::zeros(n, n),
            p_prev: None,
            var: 0.0,
        }
    }

    /// Add step k: its error map `A_k` (n × n), posterior covariance `P_k` and the
    /// Cholesky factor of `P_k`.
    /// Returns this step's contribution to the variance.
    pub fn step(&mut self, a: &DMatrix<f64>, p: &DMatrix<f64>, chol: &Cholesky<f64, Dyn>) -> f64 {
        if let Some(pp) = &self.p_prev {
            self.g = a * (&self.g + pp) * a.transpose();
        }
        let cross = chol.solve(&self.g).trace();
        let inc = 2.0 * self.n as f64 + 4.0 * cross;
        self.var += inc;
        self.p_prev = Some(p.clone());
        inc
    }

    /// Add `steps` more steps that each contribute `inc` (steady state).
    pub fn extend_steady(&mut self, inc: f64, steps: usize) {
        self.var += inc * steps as f64;
    }

    /// The predicted variance of the NEES sum so far.
    pub fn variance(&self) -> f64 {
        self.var
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn nees_null_variance_matches_brute_force_double_sum() {
        // Scalar AR(1) error e_k = a e_{k-1} + w with stationary variance p: the NEES
        // ε_k = e_k²/p has Cov(ε_j, ε_k) = 2 a^{2|k-j|}, so Var(Σ ε) = Σ_j Σ_k 2 a^{2|k-j|}.
        let (a, p, t) = (0.8_f64, 3.0_f64, 25usize);
        let am = DMatrix::from_element(1, 1, a);
        let pm = DMatrix::from_element(1, 1, p);
        let chol = Cholesky::new(pm.clone()).unwrap();
        let mut nv = NeesNullVariance::new(1);
        for _ in 0..t {
            nv.step(&am, &pm, &chol);
        }
        let mut want = 0.0;
        for j in 0..t {
            for k in 0..t {
                want += 2.0 * a.powi(2 * (j as i32 - k as i32).abs());
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-12);
    }
}

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
///
/// A NEES taken on the first `n_e` of the n states only (a filter with states the truth has
/// nothing to compare with: [`NeesNullVariance::judged`]), `ε = e₁' P₁₁⁻¹ e₁` with
/// `e₁ = S e`, is the quadratic form of `M = S' P₁₁⁻¹ S`: the same argument gives
/// `Cov(ε_j, ε_k) = 2 tr(M_k Φ_kj P_j M_j P_j Φ_kj')`, so `G_k = A_k (G_{k−1} + P_{k−1}
/// M_{k−1} P_{k−1}) A_k'` and the step adds `2 n_e + 4 tr(P₁₁,k⁻¹ (G_k)₁₁)`.
#[derive(Debug, Clone)]
pub struct NeesNullVariance {
    n: usize,
    /// The states the NEES is taken on, the first ones (n for all).
    judged: usize,
    g: DMatrix<f64>,
    p_prev: Option<DMatrix<f64>>,
    /// The inverse of `p_prev`'s judged block (a NEES on some states only).
    inv_prev: Option<DMatrix<f64>>,
    /// Scratch, n × n each: `G + P_{k−1}`, `A (G + P_{k−1})`, `A'` and `P_k⁻¹ G`, so that a
    /// step allocates nothing (the products are those `a * s * a'` computes, in its order).
    sum: DMatrix<f64>,
    left: DMatrix<f64>,
    a_t: DMatrix<f64>,
    solved: DMatrix<f64>,
    var: f64,
}

impl NeesNullVariance {
    /// Start a run with state dimension `n`.
    pub fn new(n: usize) -> Self {
        NeesNullVariance {
            n,
            judged: n,
            g: DMatrix::zeros(n, n),
            p_prev: None,
            inv_prev: None,
            sum: DMatrix::zeros(n, n),
            left: DMatrix::zeros(n, n),
            a_t: DMatrix::zeros(n, n),
            solved: DMatrix::zeros(n, n),
            var: 0.0,
        }
    }

    /// Start a run with state dimension `n` whose NEES is taken on its first `judged`
    /// states only.
    pub fn judged(n: usize, judged: usize) -> Self {
        NeesNullVariance {
            judged: judged.min(n),
            ..NeesNullVariance::new(n)
        }
    }

    /// Add a step of a NEES on the first `judged` states: its error map `A_k`, posterior
    /// covariance `P_k` (n × n) and the inverse of its leading `judged × judged` block
    /// ([`crate::linalg::spd_inverse`]). Returns this step's contribution to the variance.
    pub fn step_judged(
        &mut self,
        a: &DMatrix<f64>,
        p: &DMatrix<f64>,
        p11_inv: &DMatrix<f64>,
    ) -> f64 {
        let ne = self.judged;
        if let Some(pp) = &self.p_prev {
            self.sum.copy_from(&self.g);
            if ne == self.n {
                // M = P⁻¹: P M P is P itself.
                self.sum += pp;
            } else if let Some(inv) = &self.inv_prev {
                // P M P = P[:, :ne] P₁₁⁻¹ P[:ne, :] of the previous step, whose P₁₁⁻¹ was
                // that step's `p11_inv`.
                let left = pp.columns(0, ne);
                let right = inv * left.transpose();
                self.sum.gemm(1.0, &left, &right, 1.0);
            }
            self.left.gemm(1.0, a, &self.sum, 0.0);
            a.transpose_to(&mut self.a_t);
            self.g.gemm(1.0, &self.left, &self.a_t, 0.0);
        }
        // tr(P₁₁⁻¹ G₁₁), both symmetric: no product.
        let mut cross = 0.0;
        for j in 0..ne {
            for i in 0..ne {
                cross += p11_inv[(i, j)] * self.g[(j, i)];
            }
        }
        let inc = 2.0 * ne as f64 + 4.0 * cross;
        self.var += inc;
        match &mut self.p_prev {
            Some(pp) => pp.copy_from(p),
            None => self.p_prev = Some(p.clone()),
        }
        match &mut self.inv_prev {
            Some(i) => i.copy_from(p11_inv),
            None => self.inv_prev = Some(p11_inv.clone()),
        }
        inc
    }

    /// Add step k: its error map `A_k` (n × n), posterior covariance `P_k` and the
    /// Cholesky factor of `P_k`.
    /// Returns this step's contribution to the variance.
    pub fn step(&mut self, a: &DMatrix<f64>, p: &DMatrix<f64>, chol: &Cholesky<f64, Dyn>) -> f64 {
        self.step_factored(a, p, chol.l_dirty())
    }

    /// [`Self::step`] with `P_k`'s lower Cholesky factor `l` in a plain matrix (its lower
    /// triangle is read); the same arithmetic as the factor's `solve`.
    pub fn step_factored(&mut self, a: &DMatrix<f64>, p: &DMatrix<f64>, l: &DMatrix<f64>) -> f64 {
        if let Some(pp) = &self.p_prev {
            self.sum.copy_from(&self.g);
            self.sum += pp;
            self.left.gemm(1.0, a, &self.sum, 0.0);
            a.transpose_to(&mut self.a_t);
            self.g.gemm(1.0, &self.left, &self.a_t, 0.0);
        }
        self.solved.copy_from(&self.g);
        l.solve_lower_triangular_unchecked_mut(&mut self.solved);
        l.ad_solve_lower_triangular_unchecked_mut(&mut self.solved);
        let cross = self.solved.trace();
        let inc = 2.0 * self.n as f64 + 4.0 * cross;
        self.var += inc;
        match &mut self.p_prev {
            Some(pp) => pp.copy_from(p),
            None => self.p_prev = Some(p.clone()),
        }
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

/// Streaming computation of the variance of one run's sum `Σ_k e_jk²/P_jj,k` of each state
/// component j that a filter predicts for itself if it is consistent (the per-component
/// analogue of [`NeesNullVariance`]).
///
/// With `x_k = e_jk²/P_jj,k` and `E[e_k e_l'] = Φ_kl P_l`,
/// `Cov(x_k, x_l) = 2 (Φ_kl P_l)_jj² / (P_jj,k P_jj,l)`. Writing `p_l = P_l e_j`,
/// `(Φ_kl P_l)_jj² = e_j' Φ_kl (p_l p_l') Φ_kl' e_j`, so the sum over `l < k` is
/// `e_j' G_k e_j` with the linear recursion `G_k = A_k (G_{k−1} + p_{k−1} p_{k−1}'/P_jj,k−1)
/// A_k'`, and `Var(Σ_k x_k) = Σ_k [2 + 4 (G_k)_jj / P_jj,k]`: O(n³) per component and step.
///
/// The same runs carry the first moment's null variance, for the zero-mean test: with
/// `y_k = e_jk/√P_jj,k`, `Cov(y_k, y_l) = (Φ_kl P_l)_jj / √(P_jj,k P_jj,l)` for `k > l`, and
/// the sum over `l < k` is `(h_k)_j / √P_jj,k` with the vector recursion
/// `h_k = A_k (h_{k−1} + p_{k−1}/√P_jj,k−1)`, `h_1 = 0` (because `Φ_kl = A_k Φ_{k−1,l}`), so
/// `Var(Σ_k y_k) = Σ_k [1 + 2 (h_k)_j / √P_jj,k]`: O(n²) per component and step.
///
/// The n recursions run side by side as single products (`A [G_1 … G_n]` and `A [h_1 …
/// h_n]`), in buffers allocated once: the same 2n⁴ operations a step, in two large
/// products instead of 2n small ones and their temporaries.
#[derive(Debug, Clone)]
pub struct ComponentNullVariance {
    /// `[G_1 … G_n]`, n × n².
    g: DMatrix<f64>,
    /// `[h_1 … h_n]`, n × n.
    h: DMatrix<f64>,
    /// Scratch for `A [G_1 … G_n]` and its blocks transposed, n × n² each, and for
    /// `A [h_1 … h_n]`, n × n.
    ag: DMatrix<f64>,
    ag_t: DMatrix<f64>,
    ah: DMatrix<f64>,
    /// `P_{k−1}` once a step was added.
    p_prev: Option<DMatrix<f64>>,
    var: Vec<f64>,
    mean_var: Vec<f64>,
}

impl ComponentNullVariance {
    /// Start a run with state dimension `n`.
    pub fn new(n: usize) -> Self {
        ComponentNullVariance {
            g: DMatrix::zeros(n, n * n),
            h: DMatrix::zeros(n, n),
            ag: DMatrix::zeros(n, n * n),
            ag_t: DMatrix::zeros(n, n * n),
            ah: DMatrix::zeros(n, n),
            p_prev: None,
            var: vec![0.0; n],
            mean_var: vec![0.0; n],
        }
    }

    /// Add step k: its error map `A_k` and posterior covariance `P_k` (n × n). Returns
    /// this step's contributions, `2n` of them: each component's second-moment variance
    /// ([`Self::variances`]) then each one's first-moment variance
    /// ([`Self::mean_variances`]), so a caller can tell a steady state from one vector.
    pub fn step(&mut self, a: &DMatrix<f64>, p: &DMatrix<f64>) -> Vec<f64> {
        let n = p.nrows();
        let ComponentNullVariance {
            g,
            h,
            ag,
            ag_t,
            ah,
            p_prev,
            ..
        } = self;
        if let Some(pp) = p_prev.as_ref() {
            for j in 0..n {
                let col = pp.column(j);
                g.columns_mut(j * n, n)
                    .ger(1.0 / pp[(j, j)], &col, &col, 1.0);
                h.column_mut(j).axpy(1.0 / pp[(j, j)].sqrt(), &col, 1.0);
            }
            ag.gemm(1.0, a, g, 0.0);
            // G_j is symmetric, so (A G_j)' = G_j A' and A (A G_j)' = A G_j A'.
            for j in 0..n {
                ag_t.columns_mut(j * n, n)
                    .tr_copy_from(&ag.columns(j * n, n));
            }
            g.gemm(1.0, a, ag_t, 0.0);
            ah.gemm(1.0, a, h, 0.0);
            std::mem::swap(h, ah);
        }
        let mut inc: Vec<f64> = (0..n)
            .map(|j| 2.0 + 4.0 * self.g[(j, j * n + j)] / p[(j, j)])
            .collect();
        inc.extend((0..n).map(|j| 1.0 + 2.0 * self.h[(j, j)] / p[(j, j)].sqrt()));
        self.add(&inc, 1);
        match &mut self.p_prev {
            Some(pp) => pp.copy_from(p),
            None => self.p_prev = Some(p.clone()),
        }
        inc
    }

    fn add(&mut self, inc: &[f64], steps: usize) {
        let n = self.var.len();
        for (v, i) in self.var.iter_mut().zip(&inc[..n]) {
            *v += i * steps as f64;
        }
        for (v, i) in self.mean_var.iter_mut().zip(&inc[n..]) {
            *v += i * steps as f64;
        }
    }

    /// Add `steps` more steps that each contribute `inc` (steady state; `inc` as returned
    /// by [`Self::step`]).
    pub fn extend_steady(&mut self, inc: &[f64], steps: usize) {
        self.add(inc, steps);
    }

    /// The predicted variance of each component's sum of `e_j²/P_jj` so far.
    pub fn variances(&self) -> &[f64] {
        &self.var
    }

    /// The predicted variance of each component's sum of `e_j/√P_jj` so far.
    pub fn mean_variances(&self) -> &[f64] {
        &self.mean_var
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
        // The same NEES judged on all of its (one) states, weighed by P⁻¹.
        let mut judged = NeesNullVariance::judged(1, 1);
        let p_inv = DMatrix::from_element(1, 1, 1.0 / p);
        for _ in 0..t {
            nv.step(&am, &pm, &chol);
            judged.step_judged(&am, &pm, &p_inv);
        }
        assert_relative_eq!(judged.variance(), nv.variance(), max_relative = 1e-14);
        let mut want = 0.0;
        for j in 0..t {
            for k in 0..t {
                want += 2.0 * a.powi(2 * (j as i32 - k as i32).abs());
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-12);
    }

    #[test]
    fn nees_null_variance_on_the_first_states_matches_brute_force_double_sum() {
        // A NEES on state 0 of two: ε_k = e_0k²/P_00, Cov(ε_k, ε_l) = 2 (A^{|k−l|} P)_00² /
        // P_00², as for a component.
        let a = DMatrix::from_row_slice(2, 2, &[0.9, 0.2, -0.1, 0.7]);
        let p = DMatrix::from_row_slice(2, 2, &[2.0, 0.3, 0.3, 1.0]);
        let p11_inv = DMatrix::from_element(1, 1, 0.5);
        let t = 20;
        let mut nv = NeesNullVariance::judged(2, 1);
        for _ in 0..t {
            nv.step_judged(&a, &p, &p11_inv);
        }
        let mut powers = vec![DMatrix::identity(2, 2)];
        for i in 1..t {
            powers.push(&a * &powers[i - 1]);
        }
        let mut want = 0.0;
        for k in 0..t {
            for l in 0..t {
                let c = (&powers[k.abs_diff(l)] * &p)[(0, 0)];
                want += 2.0 * c * c / 4.0;
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-12);
    }

    #[test]
    fn nees_null_variance_on_two_of_three_states_matches_brute_force_double_sum() {
        // A NEES on states 0 and 1 of three: ε_k = e₁ₖ' P₁₁⁻¹ e₁ₖ, and with C = (A^{|k−l|}
        // P)₁₁ the cross-covariance of e₁ₖ and e₁ₗ, Isserlis gives Cov(ε_k, ε_l) =
        // 2 tr(P₁₁⁻¹ C P₁₁⁻¹ C') (2 · 2 = 4 on the diagonal: two judged states, not one).
        let a = DMatrix::from_row_slice(3, 3, &[0.9, 0.2, 0.0, -0.1, 0.7, 0.1, 0.05, 0.0, 0.5]);
        let p = DMatrix::from_row_slice(3, 3, &[2.0, 0.3, 0.1, 0.3, 1.0, -0.2, 0.1, -0.2, 0.8]);
        let p11 = p.view((0, 0), (2, 2)).clone_owned();
        let p11_inv = p11.try_inverse().unwrap();
        let t = 15;
        let mut nv = NeesNullVariance::judged(3, 2);
        let first = nv.step_judged(&a, &p, &p11_inv);
        assert_relative_eq!(first, 4.0, max_relative = 1e-12);
        for _ in 1..t {
            nv.step_judged(&a, &p, &p11_inv);
        }
        let mut powers = vec![DMatrix::identity(3, 3)];
        for i in 1..t {
            powers.push(&a * &powers[i - 1]);
        }
        let mut want = 0.0;
        for k in 0..t {
            for l in 0..t {
                let c = (&powers[k.abs_diff(l)] * &p)
                    .view((0, 0), (2, 2))
                    .clone_owned();
                want += 2.0 * (&p11_inv * &c * &p11_inv * c.transpose()).trace();
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-12);
    }

    #[test]
    fn component_null_variance_matches_brute_force_double_sum() {
        // A fixed error map and covariance: Cov(x_k, x_l) = 2 (A^{|k−l|} P)_jj² / P_jj².
        let a = DMatrix::from_row_slice(2, 2, &[0.9, 0.2, -0.1, 0.7]);
        let p = DMatrix::from_row_slice(2, 2, &[2.0, 0.3, 0.3, 1.0]);
        let t = 20;
        let mut cv = ComponentNullVariance::new(2);
        for _ in 0..t {
            cv.step(&a, &p);
        }
        let mut powers = vec![DMatrix::identity(2, 2)];
        for i in 1..t {
            powers.push(&a * &powers[i - 1]);
        }
        for j in 0..2 {
            let mut want = 0.0;
            for k in 0..t {
                for l in 0..t {
                    let c = (&powers[k.abs_diff(l)] * &p)[(j, j)];
                    want += 2.0 * c * c / (p[(j, j)] * p[(j, j)]);
                }
            }
            assert_relative_eq!(cv.variances()[j], want, max_relative = 1e-12);
        }
    }

    #[test]
    fn component_mean_null_variance_matches_brute_force_double_sum() {
        // Cov(y_k, y_l) = (A^{|k−l|} P)_jj / P_jj for a fixed map and covariance, and a
        // covariance that changes at first, so the √P_jj,k normalizations differ by step.
        let a = DMatrix::from_row_slice(3, 3, &[0.9, 0.2, 0.0, -0.1, 0.7, 0.1, 0.05, 0.0, 0.8]);
        let t = 18;
        let ps: Vec<DMatrix<f64>> = (0..t)
            .map(|k| {
                let s = 1.0 + 2.0 / (1.0 + k as f64);
                DMatrix::from_row_slice(3, 3, &[2.0 * s, 0.3, -0.2, 0.3, 1.0, 0.1, -0.2, 0.1, s])
            })
            .collect();
        let mut cv = ComponentNullVariance::new(3);
        for p in &ps {
            cv.step(&a, p);
        }
        for j in 0..3 {
            let mut want = 0.0;
            for k in 0..t {
                for l in 0..t {
                    // E[e_k e_l'] = A^{k−l} P_l for k ≥ l.
                    let (hi, lo) = (k.max(l), k.min(l));
                    let c = (a.pow((hi - lo) as u32) * &ps[lo])[(j, j)];
                    want += c / (ps[k][(j, j)] * ps[l][(j, j)]).sqrt();
                }
            }
            assert_relative_eq!(cv.mean_variances()[j], want, max_relative = 1e-12);
        }
        // A wrong recursion (h without the map) would not match: guard against a test
        // that cannot fail by checking the correlation matters here.
        let white: f64 = t as f64;
        assert!((cv.mean_variances()[0] - white).abs() > 1.0);
    }

    /// A time-varying error map `A_k` and covariance `P_k` (3 × 3, symmetric positive
    /// definite at every step): `P_k` changes by tens of percent from step to step, so a
    /// recursion that reads the current step's P where the previous one belongs is off by
    /// as much.
    fn varying(t: usize) -> (Vec<DMatrix<f64>>, Vec<DMatrix<f64>>) {
        let maps = (0..t)
            .map(|k| {
                let s = (k as f64 * 0.7).sin();
                DMatrix::from_row_slice(
                    3,
                    3,
                    &[
                        0.9 - 0.1 * s,
                        0.2,
                        0.0,
                        -0.1,
                        0.7 + 0.1 * s,
                        0.1,
                        0.05,
                        0.1 * s,
                        0.8,
                    ],
                )
            })
            .collect();
        let covs = (0..t)
            .map(|k| {
                let s = 1.0 + 0.5 * (k as f64 * 1.3).cos();
                let c = 0.3 * (k as f64 * 0.4).sin();
                DMatrix::from_row_slice(3, 3, &[2.0 * s, c, -0.2, c, 1.0 / s, 0.1, -0.2, 0.1, s])
            })
            .collect();
        (maps, covs)
    }

    /// `Φ_kl = A_k A_{k−1} ⋯ A_{l+1}` (the identity for k = l), by plain products.
    fn transition(maps: &[DMatrix<f64>], k: usize, l: usize) -> DMatrix<f64> {
        let n = maps[0].nrows();
        (l + 1..=k).fold(DMatrix::identity(n, n), |phi, i| &maps[i] * phi)
    }

    #[test]
    fn nees_null_variance_with_a_time_varying_p_matches_brute_force_double_sum() {
        // Var(Σ_k ε_k) = Σ_k Σ_l Cov(ε_k, ε_l), Cov(ε_k, ε_l) = 2 tr(P_k⁻¹ Φ_kl P_l Φ_kl')
        // for k ≥ l (Isserlis; 2 n on the diagonal), summed term by term. Tolerance 1e-10
        // relative: a few hundred rounded products on either side.
        let t = 15;
        let (maps, covs) = varying(t);
        let mut nv = NeesNullVariance::new(3);
        for (a, p) in maps.iter().zip(&covs) {
            nv.step(a, p, &Cholesky::new(p.clone()).unwrap());
        }
        let mut want = 0.0;
        for k in 0..t {
            for l in 0..t {
                let (hi, lo) = (k.max(l), k.min(l));
                let phi = transition(&maps, hi, lo);
                let cross = &phi * &covs[lo] * phi.transpose();
                want += 2.0 * (covs[hi].clone().try_inverse().unwrap() * cross).trace();
            }
        }
        assert_relative_eq!(nv.variance(), want, max_relative = 1e-10);
    }

    #[test]
    fn component_null_variance_pairs_each_step_with_the_previous_p() {
        // Var(Σ_k x_k), x_k = e_jk²/P_jj,k: Cov(x_k, x_l) = 2 (Φ_kl P_l)_jj² / (P_jj,k P_jj,l)
        // for k ≥ l, summed term by term with the map and the covariance changing every
        // step (a constant P cannot tell P_{k−1} from P_k). The same for the first moment,
        // Cov(y_k, y_l) = (Φ_kl P_l)_jj / √(P_jj,k P_jj,l). Tolerance 1e-10 relative, as
        // above; reading P_k for P_{k−1} moves these sums by percents.
        let t = 15;
        let (maps, covs) = varying(t);
        let mut cv = ComponentNullVariance::new(3);
        for (a, p) in maps.iter().zip(&covs) {
            cv.step(a, p);
        }
        for j in 0..3 {
            let (mut second, mut first) = (0.0, 0.0);
            for k in 0..t {
                for l in 0..t {
                    let (hi, lo) = (k.max(l), k.min(l));
                    let c = (transition(&maps, hi, lo) * &covs[lo])[(j, j)];
                    let (pk, pl) = (covs[k][(j, j)], covs[l][(j, j)]);
                    second += 2.0 * c * c / (pk * pl);
                    first += c / (pk * pl).sqrt();
                }
            }
            let got = cv.variances()[j];
            assert!(
                (got - second).abs() <= 1e-10 * second,
                "component {j}: second-moment null variance {got} vs brute force {second}: \
                 the recursion must pair step k with the previous step's P (P_{{k−1}})"
            );
            let got = cv.mean_variances()[j];
            assert!(
                (got - first).abs() <= 1e-10 * first,
                "component {j}: first-moment null variance {got} vs brute force {first}: \
                 the recursion must pair step k with the previous step's P (P_{{k−1}})"
            );
        }
    }
}

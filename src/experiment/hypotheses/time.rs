//! A filter's process noise as continuous or piecewise-constant noise inputs, read off its
//! own Q terms, so that a term can be rebuilt for another time step or as the other kind.
//!
//! With `Λ = log F` (the dynamics over one step, the step as the time unit) a term `B` is
//! - continuous white noise of density `W` when `B = V₁(W)`, `V_τ(W) = ∫₀^τ e^{Λt} W e^{Λ't} dt`
//!   (Van Loan; `vec V_τ(W) = φ_τ(Λ⊕Λ) vec W` with `φ_τ(M) = ∫₀^τ e^{Mt} dt` and the
//!   Kronecker sum `Λ⊕Λ = Λ⊗I + I⊗Λ`), recognised by `W = V₁⁻¹(B)` being positive
//!   semidefinite; over `s` steps it is `V_s(W)`;
//! - else, when of rank one, `B = g g'` with `g = φ₁(Λ) b`: a piecewise-constant input `b`
//!   held over the step (the discrete white-noise models, DWNA); over `s` steps
//!   `g_s = φ_s(Λ) b`.

use nalgebra::DMatrix;

use crate::linalg::{expm, symmetrize, van_loan};

/// `φ_τ(M) = ∫₀^τ e^{Mt} dt`, the top-right block of `exp([[M, I], [0, 0]] τ)`.
pub(super) fn phi(m: &DMatrix<f64>, tau: f64) -> DMatrix<f64> {
    let n = m.nrows();
    let mut big = DMatrix::zeros(2 * n, 2 * n);
    big.view_mut((0, 0), (n, n)).copy_from(&(m * tau));
    big.view_mut((0, n), (n, n))
        .copy_from(&(DMatrix::<f64>::identity(n, n) * tau));
    expm(&big).view((0, n), (n, n)).clone_owned()
}

/// `Λ⊕Λ`, acting on column-major `vec`.
fn kron_sum(l: &DMatrix<f64>) -> DMatrix<f64> {
    let n = l.nrows();
    let id = DMatrix::<f64>::identity(n, n);
    l.kronecker(&id) + id.kronecker(l)
}

/// How one Q term scales with the step.
#[derive(Debug, Clone)]
pub(super) enum Input {
    /// Continuous white noise of this density.
    Continuous(DMatrix<f64>),
    /// A piecewise-constant input held over the step.
    Held(nalgebra::DVector<f64>),
    /// Neither: the term is kept as it is.
    Other(DMatrix<f64>),
}

/// The dynamics over one step and what `V₁` needs.
#[derive(Debug, Clone)]
pub(super) struct Steps {
    pub(super) log_f: DMatrix<f64>,
    ksum: DMatrix<f64>,
}

impl Steps {
    pub(super) fn new(log_f: DMatrix<f64>) -> Self {
        let ksum = kron_sum(&log_f);
        Steps { log_f, ksum }
    }

    /// What noise input the term `b` is.
    pub(super) fn input(&self, b: &DMatrix<f64>) -> Input {
        let n = b.nrows();
        let v1 = phi(&self.ksum, 1.0);
        let vec_b = nalgebra::DVector::from_column_slice(b.as_slice());
        if let Some(w) = v1.lu().solve(&vec_b) {
            let mut w = DMatrix::from_column_slice(n, n, w.as_slice());
            symmetrize(&mut w);
            let scale = b.abs().max().max(f64::MIN_POSITIVE);
            let eig = w.clone().symmetric_eigen();
            if eig.eigenvalues.iter().all(|&e| e >= -1e-9 * scale) {
                return Input::Continuous(w);
            }
        }
        let eig = b.clone().symmetric_eigen();
        let (top, at) = eig
            .eigenvalues
            .iter()
            .enumerate()
            .map(|(i, &e)| (e, i))
            .fold((f64::MIN, 0), |a, x| if x.0 > a.0 { x } else { a });
        let rest = eig
            .eigenvalues
            .iter()
            .enumerate()
            .filter(|&(i, _)| i != at)
            .all(|(_, &e)| e.abs() <= 1e-9 * top.abs());
        if top > 0.0 && rest {
            let g = eig.eigenvectors.column(at) * top.sqrt();
            if let Some(b_in) = phi(&self.log_f, 1.0).lu().solve(&g) {
                return Input::Held(b_in);
            }
        }
        Input::Other(b.clone())
    }

    /// The term over `s` steps.
    pub(super) fn over(&self, input: &Input, s: f64) -> DMatrix<f64> {
        match input {
            // Van Loan's exponential of order 2n, the same integral as `φ_s(Λ⊕Λ) vec W`'s
            // of order 2n²: a time-step trial rebuilds its Q at every evaluation (measured:
            // the Kronecker form took 7% of the explanation sample's time).
            Input::Continuous(w) => van_loan(&self.log_f, w, s),
            Input::Held(b) => {
                let g = phi(&self.log_f, s) * b;
                &g * g.transpose()
            }
            Input::Other(q) => q.clone(),
        }
    }

    /// The term as the other kind over one step: continuous noise held piecewise constant,
    /// a held input as continuous noise of the same strength; `None` for a term of neither
    /// kind.
    pub(super) fn swapped(&self, input: &Input) -> Option<DMatrix<f64>> {
        match input {
            Input::Continuous(w) => {
                let p = phi(&self.log_f, 1.0);
                let mut q = &p * w * p.transpose();
                symmetrize(&mut q);
                Some(q)
            }
            Input::Held(b) => Some(self.over(&Input::Continuous(b * b.transpose()), 1.0)),
            Input::Other(_) => None,
        }
    }

    /// The direction a term's noise enters the dynamics (unit largest entry): the top
    /// eigenvector of its density, or its held input.
    pub(super) fn direction(input: &Input) -> Option<nalgebra::DVector<f64>> {
        let v = match input {
            Input::Continuous(w) => {
                let eig = w.clone().symmetric_eigen();
                let at = eig.eigenvalues.imax();
                eig.eigenvectors.column(at).clone_owned()
            }
            Input::Held(b) => b.clone(),
            Input::Other(_) => return None,
        };
        let big = v.amax();
        (big > 0.0).then(|| v / big)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::linalg::logm;

    /// A constant-velocity block over dt: CWNA of density q is
    /// `q [[dt³/3, dt²/2], [dt²/2, dt]]`, DWNA of variance q is `q [dt²/2, dt][dt²/2, dt]'`.
    fn cv(dt: f64) -> (DMatrix<f64>, DMatrix<f64>, DMatrix<f64>) {
        let f = DMatrix::from_row_slice(2, 2, &[1.0, dt, 0.0, 1.0]);
        let c =
            DMatrix::from_row_slice(2, 2, &[dt.powi(3) / 3.0, dt * dt / 2.0, dt * dt / 2.0, dt]);
        let g = nalgebra::DVector::from_column_slice(&[dt * dt / 2.0, dt]);
        (f, c, &g * g.transpose())
    }

    #[test]
    fn terms_rebuilt_for_another_step_are_the_models_at_that_step() {
        let (f, cwna, dwna) = cv(0.5);
        let steps = Steps::new(logm(&f).unwrap());
        let (_, cwna3, dwna3) = cv(1.5);
        let c = steps.input(&cwna);
        assert!(matches!(c, Input::Continuous(_)));
        let d = steps.input(&dwna);
        assert!(matches!(d, Input::Held(_)));
        assert!((steps.over(&c, 3.0) - &cwna3).amax() < 1e-9);
        assert!((steps.over(&d, 3.0) - &dwna3).amax() < 1e-9);
        // Swapped: the continuous term held over the step is the DWNA form up to its
        // strength (rank one, along [dt²/2, dt]), and back.
        let s = steps.swapped(&c).unwrap();
        let ratio = s[(0, 0)] / dwna[(0, 0)];
        assert!((&s - &dwna * ratio).amax() < 1e-9 * ratio, "{s}");
        let back = steps.swapped(&d).unwrap();
        let r = back[(1, 1)] / cwna[(1, 1)];
        assert!((&back - &cwna * r).amax() < 1e-9 * r, "{back}");
        // Van Loan's form is the Kronecker one's integral, on dynamics that are neither
        // nilpotent nor symmetric (a damped oscillator beside a Gauss–Markov state).
        let l = DMatrix::from_row_slice(3, 3, &[-0.1, 1.0, 0.0, -0.8, -0.3, 0.2, 0.0, 0.0, -0.5]);
        let w = DMatrix::from_row_slice(3, 3, &[0.5, 0.1, 0.0, 0.1, 2.0, -0.3, 0.0, -0.3, 1.0]);
        let kron = Steps::new(l.clone());
        for s in [0.3, 1.0, 2.7] {
            let v = phi(&kron.ksum, s) * nalgebra::DVector::from_column_slice(w.as_slice());
            let v = DMatrix::from_column_slice(3, 3, v.as_slice());
            let vl = van_loan(&l, &w, s);
            assert!(
                (&vl - &v).amax() < 1e-12 * v.amax(),
                "s = {s}: {vl} against {v}"
            );
        }
        // A random walk's variance grows with the step: continuous.
        let rw = Steps::new(DMatrix::zeros(1, 1));
        let q = DMatrix::from_element(1, 1, 2.0);
        assert!((rw.over(&rw.input(&q), 4.0)[(0, 0)] - 8.0).abs() < 1e-12);
    }
}

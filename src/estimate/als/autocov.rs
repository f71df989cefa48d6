//! The two sides of every ALS problem: the fixed-gain filter's innovation autocovariances
//! over the record, and those each noise term gives through the same filter; the filter
//! they are taken of ([`AlsModel`]), its steady-state gain and the steps dropped before them.

#![allow(non_snake_case)]

use faer::Mat;
use faer::linalg::solvers::Solve;
use nalgebra::{DMatrix, DVector};

use super::super::{EstimateError, MeasurementRecord};
use crate::params::CovModel;

/// The fewest steps dropped at the start of each sequence before the autocovariances, so
/// that the filter's transient from its initial estimate does not enter them; a slowly
/// settling filter (spectral radius ρ of Ā near 1) drops until ρ^k < 1e-6.
pub const BURN_IN: usize = 50;

/// Steps dropped for a fixed-gain filter whose error dynamics have spectral radius `rho`.
fn burn_in(rho: f64) -> usize {
    if rho <= 0.0 {
        return BURN_IN;
    }
    let settle = (1e-6_f64.ln() / rho.ln()).ceil();
    if settle.is_finite() {
        BURN_IN.max(settle as usize)
    } else {
        BURN_IN
    }
}

/// The filter ALS runs: its model and the parameterized noise.
pub struct AlsModel<'a> {
    /// State transition, n × n.
    pub F: &'a DMatrix<f64>,
    /// Measurement matrix, m × n.
    pub H: &'a DMatrix<f64>,
    /// Initial estimate.
    pub x0: &'a DVector<f64>,
    /// Process noise as a function of θ.
    pub q: &'a CovModel,
    /// Measurement noise as a function of θ.
    pub r: &'a CovModel,
}

impl<'a> AlsModel<'a> {
    /// The filter of the linear problem `lin`, with its parameterized Q and R.
    pub fn of(lin: &'a crate::experiment::LinearExperiment) -> Self {
        AlsModel {
            F: &lin.filter.F,
            H: &lin.filter.H,
            x0: &lin.filter.x0,
            q: &lin.filter.q,
            r: &lin.filter.r,
        }
    }
}

/// The steady-state Kalman gain of the filter with Q and R, by iterating the Riccati
/// recursion from the identity.
fn steady_gain(
    F: &DMatrix<f64>,
    H: &DMatrix<f64>,
    Q: &DMatrix<f64>,
    R: &DMatrix<f64>,
) -> Result<DMatrix<f64>, EstimateError> {
    let n = F.nrows();
    let mut P = DMatrix::<f64>::identity(n, n);
    for _ in 0..100_000 {
        let Pp = F * &P * F.transpose() + Q;
        let S = H * &Pp * H.transpose() + R;
        let Si = S.try_inverse().ok_or(EstimateError::SingularS)?;
        let K = &Pp * H.transpose() * Si;
        let next = (DMatrix::identity(n, n) - &K * H) * &Pp;
        let change = (&next - &P).abs().max();
        P = (&next + next.transpose()) * 0.5;
        if change <= 1e-13 * P.abs().max().max(f64::MIN_POSITIVE) {
            return Ok(K);
        }
    }
    Err(EstimateError::NotSettling)
}

/// The fixed-gain filter's innovation autocovariances, and the autocovariances any noise
/// term gives through the same filter: the two sides of every ALS problem.
pub(crate) struct Autocovariances {
    H: DMatrix<f64>,
    Abar: DMatrix<f64>,
    FK: DMatrix<f64>,
    lu: faer::linalg::solvers::PartialPivLu<f64>,
    /// Lags used (0 … lags − 1).
    pub lags: usize,
    /// The empirical autocovariances `Ĉ_0 … Ĉ_{L−1}`, each m × m column-major, stacked.
    pub empirical: Vec<f64>,
    /// Innovations they were formed from.
    pub samples: usize,
    /// Spectral radius of `Ā`.
    pub spectral_radius: f64,
}

impl Autocovariances {
    /// Run the filter of `model` with the steady-state gain for `Q`, `R` over `data`.
    pub(crate) fn new(
        model: &AlsModel<'_>,
        data: &MeasurementRecord,
        Q: &DMatrix<f64>,
        R: &DMatrix<f64>,
        lags: usize,
    ) -> Result<Self, EstimateError> {
        let (F, H) = (model.F, model.H);
        let (n, m) = (F.nrows(), H.nrows());
        if !data.complete() {
            return Err(EstimateError::Gaps);
        }
        let K = steady_gain(F, H, Q, R)?;
        let Abar = F * (DMatrix::identity(n, n) - &K * H);
        let radius = Abar
            .complex_eigenvalues()
            .iter()
            .map(|c| c.norm())
            .fold(0.0, f64::max);
        if radius.is_nan() || radius >= 1.0 {
            return Err(EstimateError::Unstable(radius));
        }
        let burn = burn_in(radius);
        let mut sums = vec![DMatrix::<f64>::zeros(m, m); lags];
        let mut counts = vec![0usize; lags];
        let mut samples = 0;
        for s in &data.sequences {
            if s.steps <= burn {
                continue;
            }
            let mut x = model.x0.clone();
            let mut innov: Vec<DVector<f64>> = Vec::with_capacity(s.steps);
            for zk in s.z.chunks(m) {
                let xp = F * &x;
                let e = DVector::from_column_slice(zk) - H * &xp;
                x = &xp + &K * &e;
                innov.push(e);
            }
            let e = &innov[burn..];
            samples += e.len();
            for j in 0..lags {
                for k in j..e.len() {
                    sums[j] += &e[k] * e[k - j].transpose();
                    counts[j] += 1;
                }
            }
        }
        if counts.iter().any(|&c| c < 10 * m * m) || samples < 4 * lags {
            return Err(EstimateError::TooShort {
                lags,
                samples,
                burn,
            });
        }
        let empirical = sums
            .iter()
            .zip(&counts)
            .flat_map(|(s, &c)| (s / c as f64).iter().copied().collect::<Vec<_>>())
            .collect();
        // One Lyapunov solve per term: vec P = (I − Ā⊗Ā)⁻¹ vec(B), from one LU.
        let nn = n * n;
        let kron = Mat::<f64>::from_fn(nn, nn, |r, c| {
            let (i1, i2) = (r / n, r % n);
            let (j1, j2) = (c / n, c % n);
            let id = if r == c { 1.0 } else { 0.0 };
            id - Abar[(i1, j1)] * Abar[(i2, j2)]
        });
        Ok(Autocovariances {
            H: H.clone(),
            FK: F * &K,
            Abar,
            lu: kron.partial_piv_lu(),
            lags,
            empirical,
            samples,
            spectral_radius: radius,
        })
    }

    /// The autocovariances (stacked like [`Self::empirical`]) that a process noise term of
    /// covariance `Qt` (n × n) and a measurement noise term `Rt` (m × m) give.
    pub(crate) fn column(&self, Qt: &DMatrix<f64>, Rt: &DMatrix<f64>) -> Vec<f64> {
        let (n, H, Abar, FK) = (self.Abar.nrows(), &self.H, &self.Abar, &self.FK);
        let B = Qt + FK * Rt * FK.transpose();
        let rhs = Mat::<f64>::from_fn(n * n, 1, |r, _| B[(r / n, r % n)]);
        let sol = self.lu.solve(&rhs);
        let P = DMatrix::from_fn(n, n, |i, j| sol[(i * n + j, 0)]);
        let m = H.nrows();
        let mut out = Vec::with_capacity(self.lags * m * m);
        // Ā^j and Ā^{j−1}, advanced together.
        let mut Aj = DMatrix::<f64>::identity(n, n);
        let mut Ajm1 = DMatrix::<f64>::identity(n, n);
        for j in 0..self.lags {
            let mut C = H * &Aj * &P * H.transpose();
            if j == 0 {
                C += Rt;
            } else {
                C -= H * &Ajm1 * FK * Rt;
                Ajm1 = Abar * Ajm1;
            }
            out.extend(C.iter().copied());
            Aj = Abar * Aj;
        }
        out
    }
}

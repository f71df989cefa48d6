//! The filter a hypothesis gives at θ: the base filter with its time step, initial
//! covariance, gains or noise model changed, or with states added (a delay, sensor states,
//! a motion state).

use nalgebra::{DMatrix, DVector};

use super::build::Prep;
use super::kinds::Hypothesis;
use crate::experiment::LinearExperiment;
use crate::filter::KalmanFilter;
use crate::linalg::{expm, van_loan};
use crate::params::Coef;

/// The filter (and the map to its states) of `base` at its own values `theta` with the
/// hypothesis's values `psi`; `None` where they give no valid filter.
pub(super) fn filter(
    base: &LinearExperiment,
    prep: &Prep,
    theta: &[f64],
    psi: &[f64],
) -> Option<(KalmanFilter, Option<DMatrix<f64>>)> {
    let mut kf = base.filter_at(theta);
    let map = base.filter.map.clone();
    let m = kf.H.nrows();
    match prep.hypothesis {
        Hypothesis::TimeStep => {
            let steps = prep.steps.as_ref()?;
            let s = psi[0];
            kf.F = expm(&(&steps.log_f * s));
            kf.Q = q_of(base, theta, |t| steps.over(&prep.inputs[t], s));
            Some((kf, map))
        }
        Hypothesis::InitialCovariance => {
            kf.P0 *= psi[0];
            Some((kf, map))
        }
        Hypothesis::SensorGain | Hypothesis::MeasurementMatrix => {
            // The components rotated into each other (a misalignment: a rotation per pair),
            // then each scaled by its gain.
            let mut rot = DMatrix::<f64>::identity(m, m);
            if prep.hypothesis == Hypothesis::MeasurementMatrix {
                let mut k = m;
                for i in 0..m {
                    for j in i + 1..m {
                        let (c, s) = (psi[k].ln().cos(), psi[k].ln().sin());
                        let mut g = DMatrix::<f64>::identity(m, m);
                        g[(i, i)] = c;
                        g[(j, j)] = c;
                        g[(i, j)] = -s;
                        g[(j, i)] = s;
                        rot = g * rot;
                        k += 1;
                    }
                }
            }
            let gain = DMatrix::from_diagonal(&DVector::from_column_slice(&psi[..m]));
            kf.H = gain * rot * &kf.H;
            Some((kf, map))
        }
        Hypothesis::FullR => {
            let mut r = kf.R.clone();
            let mut k = 0;
            for i in 0..m {
                for j in i + 1..m {
                    let rho = psi[k].ln().tanh();
                    let v = rho * (kf.R[(i, i)] * kf.R[(j, j)]).sqrt();
                    r[(i, j)] = v;
                    r[(j, i)] = v;
                    k += 1;
                }
            }
            crate::linalg::is_positive_definite(&r).then(|| {
                kf.R = r;
                (kf, map)
            })
        }
        Hypothesis::NoiseKind => {
            let steps = prep.steps.as_ref()?;
            kf.Q = q_of(base, theta, |t| {
                steps
                    .swapped(&prep.inputs[t])
                    .unwrap_or_else(|| base.filter.q.terms[t].basis.clone())
            });
            Some((kf, map))
        }
        Hypothesis::Delay(d) => Some(delayed(kf, map, d)),
        Hypothesis::ColouredNoise | Hypothesis::SensorBias => {
            Some(sensor_states(kf, map, prep, psi))
        }
        Hypothesis::MotionState => Some(singer(kf, map, prep, psi)),
    }
}

/// Q from the base's terms, each basis replaced by `basis(term)`.
fn q_of(
    base: &LinearExperiment,
    theta: &[f64],
    basis: impl Fn(usize) -> DMatrix<f64>,
) -> DMatrix<f64> {
    let q = &base.filter.q;
    let mut out = DMatrix::zeros(q.dim, q.dim);
    for (t, term) in q.terms.iter().enumerate() {
        let c = match term.coef {
            Coef::Param(i) => theta[i],
            Coef::Fixed(v) => v,
        };
        out += basis(t) * c;
    }
    out
}

/// `a` in the top-left corner of a `dim`-square matrix, `b` in the bottom-right.
fn blocks(a: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let (n, k) = (a.nrows(), b.nrows());
    let mut out = DMatrix::zeros(n + k, n + k);
    out.view_mut((0, 0), (n, n)).copy_from(a);
    out.view_mut((n, n), (k, k)).copy_from(b);
    out
}

/// The map of a filter with `extra` states added after its `n` own: the base map (or the
/// identity), whose n rows make the engines judge the NEES on the filter's own states only
/// (the truth has nothing to compare the added ones with).
fn widen_map(
    map: Option<DMatrix<f64>>,
    n: usize,
    n_t: usize,
    _extra: usize,
) -> Option<DMatrix<f64>> {
    Some(map.unwrap_or_else(|| DMatrix::identity(n, n_t)))
}

/// The filter whose measurements read the state `d` steps back: the state and its `d`
/// lagged copies.
fn delayed(
    kf: KalmanFilter,
    map: Option<DMatrix<f64>>,
    d: usize,
) -> (KalmanFilter, Option<DMatrix<f64>>) {
    let n = kf.F.nrows();
    let n_t = map.as_ref().map_or(n, |m| m.ncols());
    let dim = n * (d + 1);
    let mut f = DMatrix::zeros(dim, dim);
    f.view_mut((0, 0), (n, n)).copy_from(&kf.F);
    for lag in 1..=d {
        f.view_mut((lag * n, (lag - 1) * n), (n, n))
            .fill_with_identity();
    }
    let mut h = DMatrix::zeros(kf.H.nrows(), dim);
    h.view_mut((0, d * n), (kf.H.nrows(), n)).copy_from(&kf.H);
    let mut q = DMatrix::zeros(dim, dim);
    q.view_mut((0, 0), (n, n)).copy_from(&kf.Q);
    // A lagged copy is exact, which makes the predicted covariance singular where Q is
    // (a noise model of rank below n): a jitter of 10⁻⁶ of the initial variances keeps it
    // invertible and changes nothing the statistics can see.
    for lag in 1..=d {
        for j in 0..n {
            q[(lag * n + j, lag * n + j)] = 1e-6 * kf.P0[(j, j)];
        }
    }
    let mut p0 = DMatrix::zeros(dim, dim);
    let mut x0 = DVector::zeros(dim);
    for lag in 0..=d {
        p0.view_mut((lag * n, lag * n), (n, n)).copy_from(&kf.P0);
        x0.rows_mut(lag * n, n).copy_from(&kf.x0);
    }
    let filter = KalmanFilter {
        F: f,
        H: h,
        Q: q,
        R: kf.R,
        x0,
        P0: p0,
    };
    (filter, widen_map(map, n, n_t, d * n))
}

/// A state per measurement component added to its reading: first-order Gauss–Markov noise
/// (correlation φ, stationary variance σ²) or a bias (constant; prior mean and variance).
fn sensor_states(
    kf: KalmanFilter,
    map: Option<DMatrix<f64>>,
    prep: &Prep,
    psi: &[f64],
) -> (KalmanFilter, Option<DMatrix<f64>>) {
    let (n, m) = (kf.F.nrows(), kf.H.nrows());
    let n_t = map.as_ref().map_or(n, |mm| mm.ncols());
    let bias = prep.hypothesis == Hypothesis::SensorBias;
    let mut phi = DVector::zeros(m);
    let mut drive = DVector::zeros(m);
    let mut prior = DVector::zeros(m);
    let mut mean = DVector::zeros(m);
    for j in 0..m {
        let (a, b) = (psi[2 * j], psi[2 * j + 1]);
        if bias {
            phi[j] = 1.0;
            mean[j] = a.ln() * prep.sigma_z[j];
            prior[j] = b;
        } else {
            phi[j] = a;
            drive[j] = b * (1.0 - a * a);
            prior[j] = b;
        }
    }
    let mut h = DMatrix::zeros(m, n + m);
    h.view_mut((0, 0), (m, n)).copy_from(&kf.H);
    h.view_mut((0, n), (m, m)).fill_with_identity();
    let mut x0 = DVector::zeros(n + m);
    x0.rows_mut(0, n).copy_from(&kf.x0);
    x0.rows_mut(n, m).copy_from(&mean);
    let filter = KalmanFilter {
        F: blocks(&kf.F, &DMatrix::from_diagonal(&phi)),
        H: h,
        Q: blocks(&kf.Q, &DMatrix::from_diagonal(&drive)),
        R: kf.R,
        x0,
        P0: blocks(&kf.P0, &DMatrix::from_diagonal(&prior)),
    };
    (filter, widen_map(map, n, n_t, m))
}

/// A Gauss–Markov state on each driven process-noise input (Singer): `a' = −β a + w`,
/// stationary variance σ², entering the dynamics along the input's direction; the
/// continuous system discretized over one step.
fn singer(
    kf: KalmanFilter,
    map: Option<DMatrix<f64>>,
    prep: &Prep,
    psi: &[f64],
) -> (KalmanFilter, Option<DMatrix<f64>>) {
    let steps = prep
        .steps
        .as_ref()
        .expect("a motion state needs the dynamics");
    let n = kf.F.nrows();
    let k = prep.driven.len();
    let n_t = map.as_ref().map_or(n, |mm| mm.ncols());
    let dim = n + k;
    let mut a = DMatrix::zeros(dim, dim);
    a.view_mut((0, 0), (n, n)).copy_from(&steps.log_f);
    let mut w = DMatrix::zeros(dim, dim);
    for (i, (_, dir)) in prep.driven.iter().enumerate() {
        let (beta, drive) = (psi[2 * i], psi[2 * i + 1]);
        a.view_mut((0, n + i), (n, 1)).copy_from(dir);
        a[(n + i, n + i)] = -beta;
        w[(n + i, n + i)] = drive;
    }
    let q_gm = van_loan(&a, &w, 1.0);
    let mut q = blocks(&kf.Q, &DMatrix::zeros(k, k));
    q += q_gm;
    // The state's initial variance: its stationary one, or for a slow decay (a random
    // walk) what it gathers over the run.
    let mut p0 = blocks(&kf.P0, &DMatrix::zeros(k, k));
    for i in 0..k {
        p0[(n + i, n + i)] = psi[2 * i + 1] / (2.0 * psi[2 * i] + 1.0 / prep.horizon);
    }
    let mut h = DMatrix::zeros(kf.H.nrows(), dim);
    h.view_mut((0, 0), (kf.H.nrows(), n)).copy_from(&kf.H);
    let mut x0 = DVector::zeros(dim);
    x0.rows_mut(0, n).copy_from(&kf.x0);
    let filter = KalmanFilter {
        F: expm(&a),
        H: h,
        Q: q,
        R: kf.R,
        x0,
        P0: p0,
    };
    (filter, widen_map(map, n, n_t, k))
}

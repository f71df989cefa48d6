//! Autocovariance least squares (Odelson, Rajamani & Rawlings, Automatica 42, 2006): the
//! noise parameters from the autocovariances of a stable, possibly suboptimal filter's
//! innovations, with every parameter kept ≥ 0 so that Q and R stay positive semidefinite.
//!
//! With the filter's steady-state gain K held fixed, the a priori error
//! `ε_k = x_k − x̂⁻_k` obeys `ε_{k+1} = Ā ε_k + w_k − F K v_k`, `Ā = F (I − K H)`, and the
//! innovation is `e_k = H ε_k + v_k`. In steady state, with `P = Ā P Ā' + Q + F K R K' F'`,
//!
//! `C_0 = H P H' + R`, `C_j = H Ā^j P H' − H Ā^{j−1} F K R` (j ≥ 1),
//!
//! all linear in Q and R. With `Q = Σ θ_i Q_i` and `R = Σ θ_i R_i` each parameter has its
//! own autocovariance column (its P from one Lyapunov solve, `vec P = (I − Ā⊗Ā)⁻¹ vec(·)`,
//! done with one LU of the n² × n² Kronecker matrix in faer), the empirical `Ĉ_0 … Ĉ_{L−1}`
//! are the right-hand side, and the least-squares problem with θ ≥ 0 is a small convex QP
//! solved by clarabel from its normal equations (assembled in faer). No filter runs per
//! iteration, and a fixed gain that is far from optimal still gives the right answer as long
//! as Ā is stable.

#![allow(non_snake_case)]

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettings, DefaultSolver, IPSolver, NonnegativeConeT, SolverStatus, SupportedConeT,
};
use faer::Mat;
use faer::linalg::solvers::Solve;
use nalgebra::DMatrix;
use serde::Serialize;

mod autocov;

pub(crate) use autocov::Autocovariances;
pub use autocov::{AlsModel, BURN_IN};

use super::{EstimateError, MeasurementRecord};
use crate::params::Coef;

/// The ALS estimate.
#[derive(Debug, Clone, Serialize)]
pub struct AlsEstimate {
    /// Every parameter's value (fixed ones as given).
    pub theta: Vec<f64>,
    /// What unconstrained least squares gives (may be negative: a variance below zero).
    pub unconstrained: Vec<f64>,
    /// Free parameters the constraint holds at zero.
    pub at_zero: Vec<usize>,
    /// Root-mean-square residual of the fitted autocovariances (measurement units squared).
    pub residual: f64,
    /// Lags used.
    pub lags: usize,
    /// Innovations the autocovariances were formed from.
    pub samples: usize,
    /// Spectral radius of `Ā = F (I − K H)`: the fixed-gain filter's error dynamics.
    pub spectral_radius: f64,
    /// Passes run (each after the first with the gain at the previous estimate).
    pub passes: usize,
}

/// Which covariance ALS estimates as a full symmetric matrix constrained positive
/// semidefinite (the `sdp` feature), instead of the problem's nonnegative parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum FullMatrix {
    /// The covariance of the process noise inputs.
    Q,
    /// The measurement noise covariance.
    R,
    /// Both.
    #[serde(rename = "qr")]
    Both,
}

impl FullMatrix {
    /// "q", "r" or "qr", as the command line spells them.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "q" | "Q" => Some(Self::Q),
            "r" | "R" => Some(Self::R),
            "qr" | "QR" | "both" => Some(Self::Both),
            _ => None,
        }
    }

    /// The matrix in words.
    pub fn name(self) -> &'static str {
        match self {
            Self::Q => "Q",
            Self::R => "R",
            Self::Both => "Q and R",
        }
    }
}

/// [`estimate`] repeated `passes` times, each pass with the steady-state gain of the filter
/// at the previous pass's estimate (the first at `start`): a gain far from the optimal one
/// gives a consistent but noisy estimate, and the gain at a first estimate is near optimal,
/// so a second pass recovers most of the efficiency (measured on seven cv2d records of
/// 20 000 steps from all parameters = 1: the worst parameter's error went from 26% to 4%).
pub fn estimate_passes(
    model: &AlsModel<'_>,
    data: &MeasurementRecord,
    start: &[f64],
    fixed: &[bool],
    lags: usize,
    passes: usize,
) -> Result<AlsEstimate, EstimateError> {
    let first = estimate(model, data, start, fixed, lags)?;
    Ok(more_passes(
        first,
        passes,
        |e| &mut e.passes,
        // A parameter held at zero would give a degenerate gain (a filter that stops
        // correcting what that noise drives, with Ā at the edge of stability): the pass
        // that found it stands.
        |e| !e.at_zero.is_empty(),
        |e| estimate(model, data, &e.theta, fixed, lags),
    ))
}

/// `first` and up to `passes − 1` passes more, each `again` at the estimate before it
/// (counted in the estimate's `passes_of`), until an estimate `stands` as it is; a pass
/// that fails leaves the one before it standing (the gain at its estimate could not be
/// used). The ALS of parameterized terms and of full matrices repeat their passes so.
pub(crate) fn more_passes<E>(
    first: E,
    passes: usize,
    passes_of: fn(&mut E) -> &mut usize,
    stands: impl Fn(&E) -> bool,
    again: impl Fn(&E) -> Result<E, EstimateError>,
) -> E {
    let mut est = first;
    for _ in 1..passes {
        if stands(&est) {
            break;
        }
        match again(&est) {
            Ok(mut next) => {
                *passes_of(&mut next) = *passes_of(&mut est) + 1;
                est = next;
            }
            Err(_) => break,
        }
    }
    est
}

/// The least-squares fit of `cols` (k columns of `rows` values) to `b` with the unknowns in
/// `cones` (clarabel's, in the columns' order): the constrained solution and the
/// unconstrained one. The normal equations are formed in faer; clarabel solves
/// min ½ x'(A'A)x − (A'b)'x subject to −x + s = 0, s in the cones.
pub(crate) fn constrained_ls(
    cols: &[Vec<f64>],
    b: &[f64],
    cones: &[SupportedConeT<f64>],
) -> Result<(Vec<f64>, Vec<f64>), EstimateError> {
    let (rows, k) = (b.len(), cols.len());
    if k == 0 {
        return Err(EstimateError::NothingToEstimate);
    }
    // The right-hand side at unit norm, and the solution scaled back: autocovariances of
    // 1e-5 rad² would put the whole objective below the solver's absolute tolerances (a
    // positive scale keeps every cone what it is).
    let b_norm = b.iter().map(|v| v * v).sum::<f64>().sqrt();
    let b_scale = if b_norm > 0.0 && b_norm.is_finite() {
        b_norm
    } else {
        1.0
    };
    let A = Mat::<f64>::from_fn(rows, k, |r, c| cols[c][r]);
    let bm = Mat::<f64>::from_fn(rows, 1, |r, _| b[r] / b_scale);
    let ata = A.transpose() * &A;
    let atb = A.transpose() * &bm;
    let unconstrained = ata.partial_piv_lu().solve(&atb);
    let mut colptr = vec![0usize];
    let (mut rowval, mut nzval) = (Vec::new(), Vec::new());
    for c in 0..k {
        for r in 0..=c {
            rowval.push(r);
            nzval.push(ata[(r, c)]);
        }
        colptr.push(rowval.len());
    }
    let Pm = CscMatrix::new(k, k, colptr, rowval, nzval);
    let q: Vec<f64> = (0..k).map(|i| -atb[(i, 0)]).collect();
    let Am = CscMatrix::new(k, k, (0..=k).collect(), (0..k).collect(), vec![-1.0; k]);
    // Tighter than clarabel's 1e-8 defaults: a weakly determined parameter (a flat valley
    // of the objective) otherwise moves by 1e-5 of itself within the tolerance.
    let settings = DefaultSettings::<f64> {
        verbose: false,
        tol_gap_abs: 1e-11,
        tol_gap_rel: 1e-11,
        tol_feas: 1e-11,
        ..DefaultSettings::default()
    };
    let mut solver = DefaultSolver::new(&Pm, &q, &Am, &vec![0.0; k], cones, settings)
        .map_err(|e| EstimateError::SolverSetup(format!("{e:?}")))?;
    solver.solve();
    if !matches!(
        solver.solution.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    ) {
        return Err(EstimateError::NotSolved(format!(
            "{:?}",
            solver.solution.status
        )));
    }
    let unc = (0..k).map(|i| unconstrained[(i, 0)] * b_scale).collect();
    let x = solver.solution.x.iter().map(|v| v * b_scale).collect();
    Ok((x, unc))
}

/// Refuse unknowns the autocovariances do not determine (`what` names them in the message):
/// a rank-deficient fit has no unique answer, whatever the solver returns.
pub(crate) fn identified(cols: &[Vec<f64>], what: &str) -> Result<(), EstimateError> {
    let (rows, k) = (cols.first().map_or(0, Vec::len), cols.len());
    if k == 0 || rows == 0 {
        return Err(EstimateError::NothingToEstimate);
    }
    let A = DMatrix::from_fn(rows, k, |r, c| cols[c][r]);
    let sv = A.singular_values();
    let top = sv.max();
    let rank = sv.iter().filter(|&&s| s > 1e-8 * top).count();
    if rank < k || !top.is_finite() {
        return Err(EstimateError::NotIdentified {
            what: what.to_string(),
            unknowns: k,
            rank,
        });
    }
    Ok(())
}

/// Root-mean-square difference between `fitted` and `b`.
pub(crate) fn rms(fitted: &[f64], b: &[f64]) -> f64 {
    let ss: f64 = fitted.iter().zip(b).map(|(f, y)| (f - y).powi(2)).sum();
    (ss / b.len().max(1) as f64).sqrt()
}

/// Estimate the parameters of `model` not `fixed` from `data` (complete records) with `lags`
/// autocovariance lags, using the steady-state gain of the filter at `start`.
pub fn estimate(
    model: &AlsModel<'_>,
    data: &MeasurementRecord,
    start: &[f64],
    fixed: &[bool],
    lags: usize,
) -> Result<AlsEstimate, EstimateError> {
    let (n, m) = (model.F.nrows(), model.H.nrows());
    let ac = Autocovariances::new(
        model,
        data,
        &model.q.build(start),
        &model.r.build(start),
        lags,
    )?;
    let zq = DMatrix::<f64>::zeros(n, n);
    let zr = DMatrix::<f64>::zeros(m, m);
    let p = start.len();
    let free: Vec<usize> = (0..p).filter(|&i| !fixed[i]).collect();
    let rows = ac.empirical.len();
    // The right-hand side, less what fixed coefficients and fixed parameters contribute.
    let mut b = ac.empirical.clone();
    let mut cols: Vec<Vec<f64>> = vec![vec![0.0; rows]; p];
    for (model_q, is_q) in [(model.q, true), (model.r, false)] {
        for t in &model_q.terms {
            let col = if is_q {
                ac.column(&t.basis, &zr)
            } else {
                ac.column(&zq, &t.basis)
            };
            match t.coef {
                Coef::Param(i) if !fixed[i] => {
                    for (a, c) in cols[i].iter_mut().zip(&col) {
                        *a += c;
                    }
                }
                Coef::Param(i) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= start[i] * c),
                Coef::Fixed(v) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= v * c),
            }
        }
    }
    // Columns scaled to unit norm: the parameters' scales differ by orders of magnitude
    // (a positive scaling keeps the nonnegative cone).
    let scale: Vec<f64> = free
        .iter()
        .map(|&i| {
            cols[i]
                .iter()
                .map(|v| v * v)
                .sum::<f64>()
                .sqrt()
                .max(f64::MIN_POSITIVE)
        })
        .collect();
    let scaled: Vec<Vec<f64>> = free
        .iter()
        .zip(&scale)
        .map(|(&i, s)| cols[i].iter().map(|v| v / s).collect())
        .collect();
    identified(&scaled, "the parameters are")?;
    let (x, unc) = constrained_ls(&scaled, &b, &[NonnegativeConeT(free.len())])?;
    let mut theta = start.to_vec();
    let mut unconstrained = start.to_vec();
    let mut at_zero = Vec::new();
    // The interior-point solution approaches an active bound to its tolerance, not exactly:
    // in the unit-norm coordinates a value this far below the largest is the bound.
    let largest = x.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    for (c, &i) in free.iter().enumerate() {
        theta[i] = if x[c] <= 1e-6 * largest {
            at_zero.push(i);
            0.0
        } else {
            x[c] / scale[c]
        };
        unconstrained[i] = unc[c] / scale[c];
    }
    let fitted: Vec<f64> = (0..rows)
        .map(|r| free.iter().map(|&i| theta[i] * cols[i][r]).sum::<f64>())
        .collect();
    Ok(AlsEstimate {
        theta,
        unconstrained,
        at_zero,
        residual: rms(&fitted, &b),
        lags,
        samples: ac.samples,
        spectral_radius: ac.spectral_radius,
        passes: 1,
    })
}

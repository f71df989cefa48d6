//! Autocovariance least squares with a full unknown Q or R (Odelson, Rajamani & Rawlings
//! 2006, their semidefinite-constrained form): the covariance of the process noise inputs,
//! or of the measurement noise, as one symmetric matrix constrained positive semidefinite
//! by clarabel's semidefinite cone, instead of one nonnegative number per term.
//!
//! The process noise inputs come from the problem's own Q terms: each basis matrix `Q_i`
//! (symmetric PSD, rank r_i) is factored `Q_i = L_i L_i'`, and `G = [L_1 … L_k]` maps the
//! noise inputs to the state. The structured model is `Q = G diag(θ_i I_{r_i}) G'`; the full
//! one is `Q = G W G'` with any `W ⪰ 0`, so the off-diagonal entries of W are the
//! correlations between the inputs the structured model assumes away (for the
//! constant-velocity problems, between the x and y accelerations). A full R is any m × m
//! `R ⪰ 0`. The other matrix keeps its structured, nonnegative parameters.
//!
//! Built with the `sdp` feature only: clarabel's semidefinite cone needs BLAS and LAPACK.

#![allow(non_snake_case)]

use clarabel::solver::{NonnegativeConeT, PSDTriangleConeT, SupportedConeT};
use nalgebra::DMatrix;
use serde::Serialize;

use super::als::{
    AlsModel, Autocovariances, FullMatrix, constrained_ls, identified, more_passes, rms,
};
use super::{EstimateError, MeasurementRecord};
use crate::params::{Coef, CovModel};

/// Eigenvalues this far below the largest count as zero (rank of a basis, the boundary of
/// the cone).
const REL_ZERO: f64 = 1e-9;

/// The estimate with a full Q or R.
#[derive(Debug, Clone, Serialize)]
pub struct FullEstimate {
    /// Which matrices were full.
    pub full: FullMatrix,
    /// For each process noise input (column of G), the index of the Q term it comes from.
    pub input_terms: Vec<usize>,
    /// The noise input matrix G, n × k (rows of the serialized form are G's rows).
    #[serde(serialize_with = "rows")]
    pub G: DMatrix<f64>,
    /// Covariance of the process noise inputs W, k × k (Q = G W G'); units of each input's
    /// parameter.
    #[serde(serialize_with = "rows")]
    pub W: DMatrix<f64>,
    /// The process noise covariance Q, n × n.
    #[serde(serialize_with = "rows")]
    pub Q: DMatrix<f64>,
    /// The measurement noise covariance R, m × m.
    #[serde(serialize_with = "rows")]
    pub R: DMatrix<f64>,
    /// Every parameter: the structured matrix's estimated, the rest as started (a full Q
    /// takes the place of every Q term, fixed ones included).
    pub theta: Vec<f64>,
    /// Free parameters of the structured matrix the constraint holds at zero.
    pub at_zero: Vec<usize>,
    /// Smallest eigenvalue of W (Q full) and R (R full) as the solver returned them: at
    /// least −1e-6 of the largest (an estimate beyond that is refused); the reported
    /// matrices have such round-off-sized negative eigenvalues set to zero.
    pub min_eigenvalue: [Option<f64>; 2],
    /// The same for the unconstrained least-squares solution (negative: indefinite).
    pub unconstrained_min_eigenvalue: [Option<f64>; 2],
    /// Root-mean-square residual of the fitted autocovariances (measurement units squared).
    pub residual: f64,
    /// The same for the unconstrained solution with its negative eigenvalues (and negative
    /// parameters) set to zero: a feasible point, so never below `residual`.
    pub projected_residual: f64,
    /// Lags used.
    pub lags: usize,
    /// Innovations the autocovariances were formed from.
    pub samples: usize,
    /// Spectral radius of the fixed-gain filter's `F (I − K H)` in the last pass.
    pub spectral_radius: f64,
    /// Passes run.
    pub passes: usize,
}

fn rows<S: serde::Serializer>(m: &DMatrix<f64>, s: S) -> Result<S::Ok, S::Error> {
    let r: Vec<Vec<f64>> = m.row_iter().map(|r| r.iter().copied().collect()).collect();
    r.serialize(s)
}

/// The noise inputs of `q`: G's columns and, for each, the term it comes from.
pub fn noise_inputs(q: &CovModel) -> (DMatrix<f64>, Vec<usize>) {
    let n = q.dim;
    let mut cols = Vec::new();
    let mut terms = Vec::new();
    for (ti, t) in q.terms.iter().enumerate() {
        let sym = (&t.basis + t.basis.transpose()) * 0.5;
        let eig = sym.symmetric_eigen();
        let top = eig.eigenvalues.iter().fold(0.0_f64, |a, &v| a.max(v));
        for (j, &l) in eig.eigenvalues.iter().enumerate() {
            if l > REL_ZERO * top {
                // An eigenvector's sign is arbitrary; the largest entry positive makes each
                // input, and the sign of W's off-diagonal entries, mean the same every time.
                let v = eig.eigenvectors.column(j);
                let lead = v
                    .iter()
                    .fold(0.0_f64, |a, &x| if x.abs() > a.abs() { x } else { a });
                let sign = if lead < 0.0 { -1.0 } else { 1.0 };
                cols.push(v * (sign * l.sqrt()));
                terms.push(ti);
            }
        }
    }
    let G = DMatrix::from_fn(n, cols.len(), |i, j| cols[j][i]);
    (G, terms)
}

/// Triangle coordinates of a d × d symmetric matrix in clarabel's order (upper triangle by
/// columns, off-diagonal entries × √2): the basis matrix of each coordinate.
fn svec_basis(d: usize) -> Vec<DMatrix<f64>> {
    let mut out = Vec::new();
    for j in 0..d {
        for i in 0..=j {
            let mut B = DMatrix::zeros(d, d);
            if i == j {
                B[(i, i)] = 1.0;
            } else {
                B[(i, j)] = std::f64::consts::FRAC_1_SQRT_2;
                B[(j, i)] = std::f64::consts::FRAC_1_SQRT_2;
            }
            out.push(B);
        }
    }
    out
}

fn from_svec(x: &[f64], d: usize) -> DMatrix<f64> {
    svec_basis(d)
        .iter()
        .zip(x)
        .fold(DMatrix::zeros(d, d), |acc, (B, v)| acc + B * *v)
}

fn min_eig(M: &DMatrix<f64>) -> f64 {
    let sym = (M + M.transpose()) * 0.5;
    sym.symmetric_eigenvalues().min()
}

/// The nearest positive semidefinite matrix to `M` (Frobenius): its negative eigenvalues
/// (and those within round-off of zero) set to zero.
fn clamp_psd(M: &DMatrix<f64>) -> DMatrix<f64> {
    let eig = ((M + M.transpose()) * 0.5).symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0_f64, |a, &v| a.max(v));
    let vals = eig
        .eigenvalues
        .map(|v| if v <= REL_ZERO * top { 0.0 } else { v });
    let out = &eig.eigenvectors * DMatrix::from_diagonal(&vals) * eig.eigenvectors.transpose();
    (&out + out.transpose()) * 0.5
}

/// A block of unknowns: its columns (already scaled), its cone, and how to undo the
/// scaling (a PSD block's diagonal congruence, or a nonnegative block's per-column scales).
struct Block {
    cols: Vec<Vec<f64>>,
    cone: SupportedConeT<f64>,
    scale: Vec<f64>,
}

fn norm(c: &[f64]) -> f64 {
    c.iter().map(|v| v * v).sum::<f64>().sqrt()
}

/// The PSD block of a d × d matrix whose basis matrix `B` gives `column(B)`, scaled by the
/// diagonal congruence `M = D M̃ D` that brings the diagonal entries' columns to unit norm
/// (a congruence keeps the cone; one scale for the whole block would leave the entries of
/// two inputs 10⁴ apart in size 10⁸ apart in the normal equations).
fn psd_block(d: usize, column: impl Fn(&DMatrix<f64>) -> Vec<f64>) -> Block {
    let raw: Vec<Vec<f64>> = svec_basis(d).iter().map(column).collect();
    // Coordinate of entry (i, j), i ≤ j, in the upper triangle by columns.
    let at = |i: usize, j: usize| j * (j + 1) / 2 + i;
    let diag: Vec<f64> = (0..d)
        .map(|i| {
            let nn = norm(&raw[at(i, i)]);
            if nn > 0.0 && nn.is_finite() {
                1.0 / nn.sqrt()
            } else {
                1.0
            }
        })
        .collect();
    let mut cols = Vec::with_capacity(raw.len());
    for j in 0..d {
        for i in 0..=j {
            let f = diag[i] * diag[j];
            cols.push(raw[at(i, j)].iter().map(|v| v * f).collect());
        }
    }
    Block {
        cols,
        cone: PSDTriangleConeT(d),
        scale: diag,
    }
}

/// The matrix `D M̃ D` of a PSD block's solution `x` (triangle coordinates of M̃).
fn psd_unscale(x: &[f64], d: &[f64]) -> DMatrix<f64> {
    let n = d.len();
    let m = from_svec(x, n);
    DMatrix::from_fn(n, n, |i, j| d[i] * m[(i, j)] * d[j])
}

/// Relative to the largest eigenvalue, how far below zero the solver's answer may be
/// (its tolerance) before it counts as a failure rather than round-off.
const INDEFINITE: f64 = 1e-6;

/// `M` with its round-off-sized negative eigenvalues set to zero, and its smallest
/// eigenvalue before that; an error when `M` is indefinite beyond round-off.
fn settle_psd(M: &DMatrix<f64>, what: &str) -> Result<(DMatrix<f64>, f64), EstimateError> {
    let e = ((M + M.transpose()) * 0.5).symmetric_eigenvalues();
    let (low, top) = (e.min(), e.max());
    if low.is_nan() || low < -INDEFINITE * top.abs() {
        return Err(EstimateError::Indefinite {
            what: what.to_string(),
            smallest: low,
        });
    }
    Ok((clamp_psd(M), low))
}

/// The fit with the fixed gain of the filter with `gain_at`'s Q and R.
fn fit_at_gain(
    model: &AlsModel<'_>,
    data: &MeasurementRecord,
    start: &[f64],
    fixed: &[bool],
    full: FullMatrix,
    gain_at: (&DMatrix<f64>, &DMatrix<f64>),
    lags: usize,
) -> Result<FullEstimate, EstimateError> {
    let m = model.H.nrows();
    let ac = Autocovariances::new(model, data, gain_at.0, gain_at.1, lags)?;
    let (G, input_terms) = noise_inputs(model.q);
    let k = G.ncols();
    let full_q = matches!(full, FullMatrix::Q | FullMatrix::Both);
    let full_r = matches!(full, FullMatrix::R | FullMatrix::Both);
    if full_q && k == 0 {
        return Err(EstimateError::NoNoiseInputs);
    }
    let mut b = ac.empirical.clone();
    let (blocks, free) = unknowns(model, &ac, &G, full, start, fixed, &mut b);
    let all_cols: Vec<Vec<f64>> = blocks.iter().flat_map(|b| b.cols.clone()).collect();
    let cones: Vec<SupportedConeT<f64>> = blocks.iter().map(|b| b.cone.clone()).collect();
    identified(&all_cols, &format!("a full {} is", full.name()))?;
    let (x, unc) = constrained_ls(&all_cols, &b, &cones)?;
    let mut at = 0;
    let mut min_eigenvalue = [None, None];
    let mut unconstrained_min_eigenvalue = [None, None];
    let mut W = DMatrix::zeros(k, k);
    let mut R = DMatrix::zeros(m, m);
    // The unconstrained solution made semidefinite (negative eigenvalues and parameters set
    // to zero): a feasible point the constrained fit must match or beat.
    let (mut W_proj, mut R_proj) = (DMatrix::zeros(k, k), DMatrix::zeros(m, m));
    let mut blocks = blocks.iter();
    if full_q {
        let blk = blocks.next().expect("the Q block was pushed first");
        let sol = PsdSolution::of(&x, &unc, &mut at, blk, "W")?;
        (W, W_proj) = (sol.matrix, sol.projected);
        min_eigenvalue[0] = Some(sol.min_eigenvalue);
        unconstrained_min_eigenvalue[0] = Some(sol.unconstrained_min_eigenvalue);
    }
    if full_r {
        let blk = blocks.next().expect("the R block follows Q's");
        let sol = PsdSolution::of(&x, &unc, &mut at, blk, "R")?;
        (R, R_proj) = (sol.matrix, sol.projected);
        min_eigenvalue[1] = Some(sol.min_eigenvalue);
        unconstrained_min_eigenvalue[1] = Some(sol.unconstrained_min_eigenvalue);
    }
    let (theta, theta_proj, at_zero) = match blocks.next() {
        Some(blk) => structured_solution(&x[at..], &unc[at..], blk, &free, start),
        None => (start.to_vec(), start.to_vec(), Vec::new()),
    };
    let build = |W: &DMatrix<f64>, R: &DMatrix<f64>, theta: &[f64]| {
        let Q = if full_q {
            &G * W * G.transpose()
        } else {
            model.q.build(theta)
        };
        let R = if full_r {
            R.clone()
        } else {
            model.r.build(theta)
        };
        (Q, R)
    };
    let (Q, R) = build(&W, &R, &theta);
    let (Qp, Rp) = build(&W_proj, &R_proj, &theta_proj);
    if !full_q {
        // W of the structured Q, for the same report: each input's coefficient.
        for (j, &ti) in input_terms.iter().enumerate() {
            W[(j, j)] = match model.q.terms[ti].coef {
                Coef::Param(i) => theta[i],
                Coef::Fixed(v) => v,
            };
        }
    }
    Ok(FullEstimate {
        full,
        input_terms,
        G,
        residual: rms(&ac.column(&Q, &R), &ac.empirical),
        projected_residual: rms(&ac.column(&Qp, &Rp), &ac.empirical),
        W,
        Q,
        R,
        theta,
        at_zero,
        min_eigenvalue,
        unconstrained_min_eigenvalue,
        lags,
        samples: ac.samples,
        spectral_radius: ac.spectral_radius,
        passes: 1,
    })
}

/// The blocks of unknowns, in solution order: the full Q's noise-input covariance W (on
/// the inputs `G`), the full R, then the structured matrix's free parameters (their indices
/// returned beside), whose fixed contributions are taken off `b`.
fn unknowns(
    model: &AlsModel<'_>,
    ac: &Autocovariances,
    G: &DMatrix<f64>,
    full: FullMatrix,
    start: &[f64],
    fixed: &[bool],
    b: &mut [f64],
) -> (Vec<Block>, Vec<usize>) {
    let (n, m) = (model.F.nrows(), model.H.nrows());
    let (zq, zr) = (DMatrix::zeros(n, n), DMatrix::zeros(m, m));
    let mut blocks: Vec<Block> = Vec::new();
    if matches!(full, FullMatrix::Q | FullMatrix::Both) {
        blocks.push(psd_block(G.ncols(), |B| {
            ac.column(&(G * B * G.transpose()), &zr)
        }));
    }
    if matches!(full, FullMatrix::R | FullMatrix::Both) {
        blocks.push(psd_block(m, |B| ac.column(&zq, B)));
    }
    // The structured matrix: its free parameters ≥ 0, fixed ones moved to the right.
    let structured = match full {
        FullMatrix::Q => Some((model.r, false)),
        FullMatrix::R => Some((model.q, true)),
        FullMatrix::Both => None,
    };
    let mut free: Vec<usize> = Vec::new();
    if let Some((cov, is_q)) = structured {
        let column = |basis: &DMatrix<f64>| {
            if is_q {
                ac.column(basis, &zr)
            } else {
                ac.column(&zq, basis)
            }
        };
        if let Some((params, block)) = structured_block(cov, &column, start, fixed, b) {
            free = params;
            blocks.push(block);
        }
    }
    (blocks, free)
}

/// The nonnegative block of the structured matrix `cov`'s free parameters (their indices,
/// in the order of their first term), each column at unit norm (a positive diagonal scaling
/// keeps the cone); what fixed coefficients and fixed parameters contribute is taken off
/// `b`. `None` when every parameter of `cov` is fixed.
fn structured_block(
    cov: &CovModel,
    column: &dyn Fn(&DMatrix<f64>) -> Vec<f64>,
    start: &[f64],
    fixed: &[bool],
    b: &mut [f64],
) -> Option<(Vec<usize>, Block)> {
    let mut cols: Vec<(usize, Vec<f64>)> = Vec::new();
    for t in &cov.terms {
        let col = column(&t.basis);
        match t.coef {
            Coef::Param(i) if !fixed[i] => match cols.iter_mut().find(|(j, _)| *j == i) {
                Some((_, c)) => c.iter_mut().zip(&col).for_each(|(a, v)| *a += v),
                None => cols.push((i, col)),
            },
            Coef::Param(i) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= start[i] * c),
            Coef::Fixed(v) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= v * c),
        }
    }
    if cols.is_empty() {
        return None;
    }
    let free: Vec<usize> = cols.iter().map(|(i, _)| *i).collect();
    let scale: Vec<f64> = cols
        .iter()
        .map(|(_, c)| norm(c).max(f64::MIN_POSITIVE))
        .collect();
    let block = Block {
        cols: cols
            .iter()
            .zip(&scale)
            .map(|((_, c), s)| c.iter().map(|v| v / s).collect())
            .collect(),
        cone: NonnegativeConeT(free.len()),
        scale,
    };
    Some((free, block))
}

/// The structured matrix's parameters from its nonnegative block `blk` of the constrained
/// solution `x` and the unconstrained `unc` (from the block's first coordinate): θ with the
/// free parameters set (those at the bound listed), and θ of the unconstrained solution
/// projected onto the cone.
fn structured_solution(
    x: &[f64],
    unc: &[f64],
    blk: &Block,
    free: &[usize],
    start: &[f64],
) -> (Vec<f64>, Vec<f64>, Vec<usize>) {
    let mut theta = start.to_vec();
    let mut theta_proj = start.to_vec();
    let mut at_zero = Vec::new();
    // In the unit-norm coordinates a value this far below the largest is the bound.
    let top = x.iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    for (c, &i) in free.iter().enumerate() {
        let v = x[c];
        theta[i] = if v <= 1e-6 * top {
            at_zero.push(i);
            0.0
        } else {
            v / blk.scale[c]
        };
        theta_proj[i] = (unc[c] / blk.scale[c]).max(0.0);
    }
    (theta, theta_proj, at_zero)
}

/// A PSD block's share of the solution: the matrix (round-off settled), its smallest
/// eigenvalue, and the unconstrained solution's smallest eigenvalue and projection onto the
/// cone.
struct PsdSolution {
    matrix: DMatrix<f64>,
    min_eigenvalue: f64,
    unconstrained_min_eigenvalue: f64,
    projected: DMatrix<f64>,
}

impl PsdSolution {
    /// The block `blk` (the matrix called `what` in messages) of the constrained solution
    /// `x` and the unconstrained `unc`, from coordinate `at`, which moves past it.
    fn of(
        x: &[f64],
        unc: &[f64],
        at: &mut usize,
        blk: &Block,
        what: &str,
    ) -> Result<PsdSolution, EstimateError> {
        let d = blk.scale.len() * (blk.scale.len() + 1) / 2;
        let (matrix, low) = settle_psd(&psd_unscale(&x[*at..*at + d], &blk.scale), what)?;
        let u = psd_unscale(&unc[*at..*at + d], &blk.scale);
        *at += d;
        Ok(PsdSolution {
            matrix,
            min_eigenvalue: low,
            unconstrained_min_eigenvalue: min_eig(&u),
            projected: clamp_psd(&u),
        })
    }
}

/// ALS with `full` (Q, R or both) a full PSD matrix, `passes` times: the first with the
/// gain of the filter at `start`, each later one with the gain at the previous estimate
/// unless that estimate is on the boundary of the cone (a singular W or R gives a filter at
/// the edge of stability, as a zero parameter does in [`super::als::estimate_passes`]).
pub fn estimate_full(
    model: &AlsModel<'_>,
    data: &MeasurementRecord,
    start: &[f64],
    fixed: &[bool],
    full: FullMatrix,
    lags: usize,
    passes: usize,
) -> Result<FullEstimate, EstimateError> {
    let (Q0, R0) = (model.q.build(start), model.r.build(start));
    let first = fit_at_gain(model, data, start, fixed, full, (&Q0, &R0), lags)?;
    let boundary = |M: &DMatrix<f64>| {
        let e = M.symmetric_eigenvalues();
        e.min() <= 1e-6 * e.max()
    };
    Ok(more_passes(
        first,
        passes,
        |e| &mut e.passes,
        |est| {
            !est.at_zero.is_empty()
                || (est.min_eigenvalue[0].is_some() && boundary(&est.W))
                || (est.min_eigenvalue[1].is_some() && boundary(&est.R))
        },
        |est| fit_at_gain(model, data, start, fixed, full, (&est.Q, &est.R), lags),
    ))
}

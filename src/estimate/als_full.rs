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

use super::Measurements;
use super::als::{AlsModel, Autocovariances, FullMatrix, constrained_ls, rms};
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
    /// Every parameter: the structured matrix's estimated, the rest as started.
    pub theta: Vec<f64>,
    /// Smallest eigenvalue of the estimated W (Q full) and R (R full): never below zero.
    pub min_eigenvalue: [Option<f64>; 2],
    /// The same for the unconstrained least-squares solution (negative: indefinite).
    pub unconstrained_min_eigenvalue: [Option<f64>; 2],
    /// Root-mean-square residual of the fitted autocovariances (measurement units squared).
    pub residual: f64,
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
                cols.push(eig.eigenvectors.column(j) * l.sqrt());
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

/// `M` with eigenvalues below zero (the solver's tolerance, relative to the largest) set
/// to zero, so that the constraint holds to round-off rather than to the solver's
/// tolerance; and its smallest eigenvalue.
fn clamp_psd(M: &DMatrix<f64>) -> (DMatrix<f64>, f64) {
    let eig = ((M + M.transpose()) * 0.5).symmetric_eigen();
    let top = eig.eigenvalues.iter().fold(0.0_f64, |a, &v| a.max(v));
    let vals = eig
        .eigenvalues
        .map(|v| if v <= REL_ZERO * top { 0.0 } else { v });
    let out = &eig.eigenvectors * DMatrix::from_diagonal(&vals) * eig.eigenvectors.transpose();
    ((&out + out.transpose()) * 0.5, vals.min())
}

/// One pass: the gain of the filter with `Q`, `R`.
fn pass(
    model: &AlsModel<'_>,
    data: &Measurements,
    start: &[f64],
    fixed: &[bool],
    full: FullMatrix,
    gain_at: (&DMatrix<f64>, &DMatrix<f64>),
    lags: usize,
) -> Result<FullEstimate, String> {
    let (n, m) = (model.F.nrows(), model.H.nrows());
    let ac = Autocovariances::new(model, data, gain_at.0, gain_at.1, lags)?;
    let (G, input_terms) = noise_inputs(model.q);
    let k = G.ncols();
    let (zq, zr) = (DMatrix::zeros(n, n), DMatrix::zeros(m, m));
    let full_q = matches!(full, FullMatrix::Q | FullMatrix::Both);
    let full_r = matches!(full, FullMatrix::R | FullMatrix::Both);
    let mut b = ac.empirical.clone();
    // Blocks of unknowns: (columns, cone, how the block's x maps back).
    let mut blocks: Vec<(Vec<Vec<f64>>, SupportedConeT<f64>)> = Vec::new();
    if full_q {
        let cols = svec_basis(k)
            .iter()
            .map(|B| ac.column(&(&G * B * G.transpose()), &zr))
            .collect();
        blocks.push((cols, PSDTriangleConeT(k)));
    }
    if full_r {
        let cols = svec_basis(m).iter().map(|B| ac.column(&zq, B)).collect();
        blocks.push((cols, PSDTriangleConeT(m)));
    }
    // The structured matrix: its free parameters ≥ 0, fixed ones moved to the right.
    let structured: Option<(&CovModel, bool)> = match full {
        FullMatrix::Q => Some((model.r, false)),
        FullMatrix::R => Some((model.q, true)),
        FullMatrix::Both => None,
    };
    let mut free: Vec<usize> = Vec::new();
    if let Some((cov, is_q)) = structured {
        let mut cols: Vec<(usize, Vec<f64>)> = Vec::new();
        for t in &cov.terms {
            let col = if is_q {
                ac.column(&t.basis, &zr)
            } else {
                ac.column(&zq, &t.basis)
            };
            match t.coef {
                Coef::Param(i) if !fixed[i] => match cols.iter_mut().find(|(j, _)| *j == i) {
                    Some((_, c)) => c.iter_mut().zip(&col).for_each(|(a, v)| *a += v),
                    None => cols.push((i, col)),
                },
                Coef::Param(i) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= start[i] * c),
                Coef::Fixed(v) => b.iter_mut().zip(&col).for_each(|(y, c)| *y -= v * c),
            }
        }
        if !cols.is_empty() {
            free = cols.iter().map(|(i, _)| *i).collect();
            let n_free = free.len();
            blocks.push((
                cols.into_iter().map(|(_, c)| c).collect(),
                NonnegativeConeT(n_free),
            ));
        }
    }
    // One positive scale per block (the mean column norm) keeps each cone what it is and
    // brings the blocks' columns to one size.
    let mut all_cols = Vec::new();
    let mut cones = Vec::new();
    let mut scales = Vec::new();
    for (cols, cone) in blocks {
        let norm = cols
            .iter()
            .map(|c| c.iter().map(|v| v * v).sum::<f64>().sqrt())
            .sum::<f64>()
            / cols.len() as f64;
        let s = norm.max(f64::MIN_POSITIVE);
        for c in &cols {
            all_cols.push(c.iter().map(|v| v / s).collect::<Vec<f64>>());
            scales.push(s);
        }
        cones.push(cone);
    }
    identified(&all_cols, full)?;
    let (x, unc) = constrained_ls(&all_cols, &b, &cones)?;
    let x: Vec<f64> = x.iter().zip(&scales).map(|(v, s)| v / s).collect();
    let unc: Vec<f64> = unc.iter().zip(&scales).map(|(v, s)| v / s).collect();
    let mut at = 0;
    let mut min_eigenvalue = [None, None];
    let mut unconstrained_min_eigenvalue = [None, None];
    let mut W = DMatrix::zeros(k, k);
    let mut theta = start.to_vec();
    if full_q {
        let d = k * (k + 1) / 2;
        let (w, low) = clamp_psd(&from_svec(&x[at..at + d], k));
        W = w;
        min_eigenvalue[0] = Some(low);
        unconstrained_min_eigenvalue[0] = Some(min_eig(&from_svec(&unc[at..at + d], k)));
        at += d;
    }
    let mut R = DMatrix::zeros(m, m);
    if full_r {
        let d = m * (m + 1) / 2;
        let (r, low) = clamp_psd(&from_svec(&x[at..at + d], m));
        R = r;
        min_eigenvalue[1] = Some(low);
        unconstrained_min_eigenvalue[1] = Some(min_eig(&from_svec(&unc[at..at + d], m)));
        at += d;
    }
    let top = x[at..].iter().fold(0.0_f64, |a, v| a.max(v.abs()));
    for (c, &i) in free.iter().enumerate() {
        let v = x[at + c];
        theta[i] = if v <= 1e-6 * top { 0.0 } else { v };
    }
    let Q = if full_q {
        &G * &W * G.transpose()
    } else {
        model.q.build(&theta)
    };
    if !full_r {
        R = model.r.build(&theta);
    }
    if !full_q {
        // W of the structured Q, for the same report: each input's coefficient.
        for (j, &ti) in input_terms.iter().enumerate() {
            W[(j, j)] = match model.q.terms[ti].coef {
                Coef::Param(i) => theta[i],
                Coef::Fixed(v) => v,
            };
        }
    }
    let fitted = fit(&ac, &Q, &R);
    Ok(FullEstimate {
        full,
        input_terms,
        G,
        W,
        Q,
        R,
        theta,
        min_eigenvalue,
        unconstrained_min_eigenvalue,
        residual: rms(&fitted, &ac.empirical),
        lags,
        samples: ac.samples,
        spectral_radius: ac.spectral_radius,
        passes: 1,
    })
}

/// The autocovariances the estimated Q and R give through the pass's filter.
fn fit(ac: &Autocovariances, Q: &DMatrix<f64>, R: &DMatrix<f64>) -> Vec<f64> {
    ac.column(Q, R)
}

/// Refuse a problem whose unknowns the autocovariances do not determine: a full W has
/// k(k+1)/2 unknowns, and a filter that measures few of the states cannot see them all.
fn identified(cols: &[Vec<f64>], full: FullMatrix) -> Result<(), String> {
    let (rows, k) = (cols.first().map_or(0, Vec::len), cols.len());
    let A = DMatrix::from_fn(rows, k, |r, c| cols[c][r]);
    let sv = A.singular_values();
    let top = sv.max();
    let rank = sv.iter().filter(|&&s| s > 1e-8 * top).count();
    if rank < k {
        return Err(format!(
            "a full {} is not identified by these autocovariances: {k} unknowns in all, only {rank} independent (fewer noise inputs, more lags, or the structured estimate)",
            full.name()
        ));
    }
    Ok(())
}

/// ALS with `full` (Q, R or both) a full PSD matrix, `passes` times: the first with the
/// gain of the filter at `start`, each later one with the gain at the previous estimate
/// unless that estimate is on the boundary of the cone (a singular W or R gives a filter at
/// the edge of stability, as a zero parameter does in [`super::als::estimate_passes`]).
pub fn estimate_full(
    model: &AlsModel<'_>,
    data: &Measurements,
    start: &[f64],
    fixed: &[bool],
    full: FullMatrix,
    lags: usize,
    passes: usize,
) -> Result<FullEstimate, String> {
    let (Q0, R0) = (model.q.build(start), model.r.build(start));
    let mut est = pass(model, data, start, fixed, full, (&Q0, &R0), lags)?;
    for _ in 1..passes {
        let boundary = |M: &DMatrix<f64>| {
            let e = M.symmetric_eigenvalues();
            e.min() <= 1e-6 * e.max()
        };
        let on_edge = est.theta.iter().zip(fixed).any(|(v, f)| !f && *v == 0.0)
            || (est.min_eigenvalue[0].is_some() && boundary(&est.W))
            || (est.min_eigenvalue[1].is_some() && boundary(&est.R));
        if on_edge {
            break;
        }
        match pass(model, data, start, fixed, full, (&est.Q, &est.R), lags) {
            Ok(next) => {
                let done = est.passes + 1;
                est = next;
                est.passes = done;
            }
            Err(_) => break,
        }
    }
    Ok(est)
}

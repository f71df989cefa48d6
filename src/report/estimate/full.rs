//! `estimate --full`'s outputs: a full Q or R estimated under the semidefinite cone, as
//! JSON and as text with its matrices.

use std::fmt::Write;

use super::{EstimateSummary, estimate_json, input_names};
use crate::params::ParamSpace;
use crate::report::format::fmt_g;

/// A full-matrix estimate as the JSON `--json` prints.
#[cfg(feature = "sdp")]
pub fn full_json(
    summary: &EstimateSummary<'_>,
    est: &crate::estimate::als_full::FullEstimate,
    model: &crate::estimate::als::AlsModel<'_>,
    measurement_names: &[String],
) -> String {
    let mut extra = serde_json::Map::new();
    extra.insert("full".into(), serde_json::json!(est.full));
    extra.insert(
        "inputs".into(),
        serde_json::json!(input_names(summary, est, model)),
    );
    extra.insert(
        "measurement_names".into(),
        serde_json::json!(measurement_names),
    );
    estimate_json(summary, "als", est, extra)
}

/// A full-matrix estimate as a table: what each process noise input drives, the full
/// matrices with their correlations and smallest eigenvalues, the structured matrix's
/// parameters, and the fit.
#[cfg(feature = "sdp")]
pub fn full_text(
    summary: &EstimateSummary<'_>,
    est: &crate::estimate::als_full::FullEstimate,
    model: &crate::estimate::als::AlsModel<'_>,
    state_names: &[String],
    z_names: &[String],
) -> String {
    use crate::estimate::als::FullMatrix;
    use crate::params::Coef;
    let params = summary.params;
    let full = est.full;
    let inputs = input_names(summary, est, model);
    let mut text = String::new();
    let o = &mut text;
    let mut write = || -> std::fmt::Result {
        writeln!(
            o,
            "autotune estimate: {} from {} ({} sequence(s), {} innovations), autocovariance least squares with a full {} (semidefinite), lags 0..{}",
            summary.problem,
            summary.record.display(),
            summary.sequences,
            est.samples,
            full.name(),
            est.lags - 1
        )?;
        let eig = |v: Option<f64>| v.map_or("-".to_string(), fmt_g);
        if matches!(full, FullMatrix::Q | FullMatrix::Both) {
            // What each input is: its column of G, in the state's components.
            let states = state_names;
            for (j, name) in inputs.iter().enumerate() {
                let parts: Vec<String> = (0..est.G.nrows())
                    .filter(|&i| est.G[(i, j)].abs() > 0.0)
                    .map(|i| {
                        let s = states
                            .get(i)
                            .map_or_else(|| format!("x{}", i + 1), String::clone);
                        format!("{} {s}", fmt_g(est.G[(i, j)]))
                    })
                    .collect();
                writeln!(o, "input {name}: drives {}", parts.join(", "))?;
            }
            let fixed_q = model.q.terms.iter().any(|t| match t.coef {
                Coef::Param(i) => params.params[i].fixed,
                Coef::Fixed(_) => true,
            });
            if fixed_q {
                writeln!(
                    o,
                    "(the full W takes the place of every Q term, the fixed ones included)"
                )?;
            }
            matrix_lines(
                o,
                "W, the covariance of the process noise inputs (Q = G W G'; units of each input's parameter):",
                &inputs,
                &est.W,
            )?;
            writeln!(
                o,
                "  smallest eigenvalue {} (unconstrained least squares: {})",
                eig(est.min_eigenvalue[0]),
                eig(est.unconstrained_min_eigenvalue[0])
            )?;
        }
        if matches!(full, FullMatrix::R | FullMatrix::Both) {
            matrix_lines(o, "R, the measurement noise covariance:", z_names, &est.R)?;
            writeln!(
                o,
                "  smallest eigenvalue {} (unconstrained least squares: {})",
                eig(est.min_eigenvalue[1]),
                eig(est.unconstrained_min_eigenvalue[1])
            )?;
        }
        // The structured matrix's parameters, as `estimate --method als` prints them.
        let structured = match full {
            FullMatrix::Q => Some(model.r),
            FullMatrix::R => Some(model.q),
            FullMatrix::Both => None,
        };
        if let Some(cov) = structured {
            structured_lines(o, params, cov, &est.theta)?;
        }
        writeln!(
            o,
            "rms residual of the autocovariances {} (the unconstrained solution made semidefinite: {}); {} pass(es), last filter's spectral radius of F(I − KH) {:.4}; {:.3} s",
            fmt_g(est.residual),
            fmt_g(est.projected_residual),
            est.passes,
            est.spectral_radius,
            summary.seconds
        )
    };
    let _ = write();
    text
}

/// A named square matrix as a table, then the correlation of each pair of its components
/// (correlations say more than covariances about what a structured model misses).
#[cfg(feature = "sdp")]
fn matrix_lines(
    o: &mut String,
    title: &str,
    names: &[String],
    m: &nalgebra::DMatrix<f64>,
) -> std::fmt::Result {
    writeln!(o, "{title}")?;
    let w = names
        .iter()
        .map(|s| s.chars().count())
        .max()
        .unwrap_or(0)
        .max(12);
    write!(o, "  {:<w$}", "")?;
    for n in names {
        write!(o, " {n:>w$}")?;
    }
    writeln!(o)?;
    for (i, n) in names.iter().enumerate() {
        write!(o, "  {n:<w$}")?;
        for j in 0..names.len() {
            write!(o, " {:>w$}", fmt_g(m[(i, j)]))?;
        }
        writeln!(o)?;
    }
    // Correlations say more than covariances about what the structured model misses.
    for i in 0..names.len() {
        for j in i + 1..names.len() {
            let d = (m[(i, i)] * m[(j, j)]).sqrt();
            if d > 0.0 {
                writeln!(
                    o,
                    "  correlation {} – {}: {:.3}",
                    names[i],
                    names[j],
                    m[(i, j)] / d
                )?;
            }
        }
    }
    Ok(())
}

/// The parameters of the matrix that stayed structured (Q when R is full, R when Q is),
/// each once, with its estimate and unit.
#[cfg(feature = "sdp")]
fn structured_lines(
    o: &mut String,
    params: &ParamSpace,
    cov: &crate::params::CovModel,
    theta: &[f64],
) -> std::fmt::Result {
    use crate::params::Coef;
    let mut shown = Vec::new();
    for t in &cov.terms {
        if let Coef::Param(i) = t.coef {
            if shown.contains(&i) {
                continue;
            }
            shown.push(i);
            let d = &params.params[i];
            writeln!(
                o,
                "{:<14} {:>12}  {}{}",
                d.name,
                fmt_g(theta[i]),
                d.unit,
                if d.fixed { " (fixed)" } else { "" }
            )?;
        }
    }
    Ok(())
}

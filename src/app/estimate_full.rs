//! `estimate --method als --full q|r|qr`: a full Q or R by autocovariance least squares
//! with a semidefinite constraint (the `sdp` build feature).

use std::path::Path;
use std::process::ExitCode;

use super::AppError;
use crate::estimate::Measurements;
use crate::estimate::als::{AlsModel, FullMatrix};
use crate::problem::Problem;

/// Run the full-matrix estimate and print it.
#[cfg(not(feature = "sdp"))]
#[allow(clippy::too_many_arguments)]
pub(super) fn run(
    _p: &Problem,
    _record: &Path,
    _data: &Measurements,
    _model: &AlsModel<'_>,
    _start: &[f64],
    _fixed: &[bool],
    _full: FullMatrix,
    _lags: usize,
    _passes: usize,
    _json: bool,
) -> Result<ExitCode, AppError> {
    Err(AppError::flag(
        "--full",
        "this autotune was built without the `sdp` feature (clarabel's semidefinite cone needs a system OpenBLAS: apt-get install libopenblas-dev, then cargo build --release --features sdp)",
    ))
}

/// Run the full-matrix estimate and print it.
#[cfg(feature = "sdp")]
#[allow(clippy::too_many_arguments)]
pub(super) fn run(
    p: &Problem,
    record: &Path,
    data: &Measurements,
    model: &AlsModel<'_>,
    start: &[f64],
    fixed: &[bool],
    full: FullMatrix,
    lags: usize,
    passes: usize,
    json: bool,
) -> Result<ExitCode, AppError> {
    use super::print_stdout;
    use crate::estimate::als_full::estimate_full;
    use crate::experiment::Experiment;
    use crate::params::Coef;
    use crate::report::fmt_g;

    let t0 = std::time::Instant::now();
    let est = estimate_full(model, data, start, fixed, full, lags, passes)
        .map_err(|m| AppError::Refused(format!("{}: {m}", record.display())))?;
    let took = t0.elapsed().as_secs_f64();
    let params = p.params();
    // Each noise input is named after its Q term's parameter (with an index when the term
    // has more than one input).
    let inputs: Vec<String> = est
        .input_terms
        .iter()
        .enumerate()
        .map(|(j, &ti)| {
            let base = match model.q.terms[ti].coef {
                Coef::Param(i) => params.params[i].name.clone(),
                Coef::Fixed(_) => format!("fixed term {}", ti + 1),
            };
            let of_term: Vec<usize> = (0..est.input_terms.len())
                .filter(|&k| est.input_terms[k] == ti)
                .collect();
            if of_term.len() > 1 {
                let pos = of_term.iter().position(|&k| k == j).unwrap_or(0);
                format!("{base}[{pos}]")
            } else {
                base
            }
        })
        .collect();
    let exp = p.experiment();
    let z_names: Vec<String> = exp.measurement_names().to_vec();
    print_stdout(|o| {
        if json {
            let value = serde_json::json!({
                "problem": p.name(),
                "method": "als",
                "full": full,
                "inputs": inputs,
                "measurement_names": z_names,
                "params": params.names(),
                "estimate": est,
                "seconds": took,
            });
            return writeln!(
                o,
                "{}",
                serde_json::to_string_pretty(&value).expect("serializes")
            );
        }
        writeln!(
            o,
            "autotune estimate: {} from {} ({} sequence(s), {} innovations), autocovariance least squares with a full {} (semidefinite), lags 0..{}",
            p.name(),
            record.display(),
            data.sequences.len(),
            est.samples,
            full.name(),
            est.lags - 1
        )?;
        let matrix = |o: &mut dyn std::io::Write,
                      title: &str,
                      names: &[String],
                      m: &nalgebra::DMatrix<f64>|
         -> std::io::Result<()> {
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
        };
        let eig = |v: Option<f64>| v.map_or("-".to_string(), fmt_g);
        if matches!(full, FullMatrix::Q | FullMatrix::Both) {
            // What each input is: its column of G, in the state's components.
            let states = exp.state_names();
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
            matrix(
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
            matrix(o, "R, the measurement noise covariance:", &z_names, &est.R)?;
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
                        fmt_g(est.theta[i]),
                        d.unit,
                        if d.fixed { " (fixed)" } else { "" }
                    )?;
                }
            }
        }
        writeln!(
            o,
            "rms residual of the autocovariances {} (the unconstrained solution made semidefinite: {}); {} pass(es), last filter's spectral radius of F(I − KH) {:.4}; {:.3} s",
            fmt_g(est.residual),
            fmt_g(est.projected_residual),
            est.passes,
            est.spectral_radius,
            took
        )
    })?;
    Ok(ExitCode::SUCCESS)
}

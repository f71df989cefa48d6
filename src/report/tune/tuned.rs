//! Tuned configs: the parameter values (and the Q and R they give) that `autotune check
//! --config` applies on top of a problem file, with the provenance of the tuning run.

use std::path::Path;

use indexmap::IndexMap;
use serde::{Deserialize, Serialize};

use crate::experiment::Experiment;
use crate::input::{FileError, parse_toml};
use crate::params::ParamSpace;
use crate::tune::TuneResult;
use crate::userfile::read_text;

/// A tuned config as stored on disk.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct TunedConfig {
    /// Name of the problem it was tuned for.
    pub problem: String,
    /// Process noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "Q", skip_serializing_if = "Option::is_none")]
    pub q: Option<Vec<Vec<f64>>>,
    /// Measurement noise covariance the parameters give, rows (informational).
    #[serde(default, rename = "R", skip_serializing_if = "Option::is_none")]
    pub r: Option<Vec<Vec<f64>>>,
    /// Parameter values by name: what `check --config` applies.
    pub params: IndexMap<String, f64>,
    /// Search bounds the tuning run widened, by parameter name: `[lower, upper]` in the
    /// parameter's units. Written only when a bound was widened, because the tuned value
    /// may then lie outside the problem file's bounds: these are the bounds it needs (copy
    /// them into the problem file to tune from it again). When given, each must name a
    /// parameter, satisfy 0 < lower < upper, and hold that parameter's value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bounds: Option<IndexMap<String, [f64; 2]>>,
    /// How the values were obtained (not read back).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub provenance: Option<toml::Table>,
}

/// Provenance recorded in a tuned config.
#[derive(Debug, Clone, Serialize)]
struct Provenance {
    autotune_version: &'static str,
    problem_file: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    problem_sha256: Option<String>,
    status: String,
    scoring: String,
    search_seed: toml::Value,
    confirm_seed: toml::Value,
    runs: usize,
    steps: usize,
    alpha: f64,
    objective: f64,
    evaluations: usize,
    diverged_evaluations: usize,
    confirmation: Confirmation,
}

#[derive(Debug, Clone, Serialize)]
struct Confirmation {
    seeds: usize,
    passed: usize,
    band_low: usize,
    /// Confirmed on the recorded measurements the search scored on (no fresh seeds);
    /// written only then.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    recorded: bool,
    verdict: String,
    anees: Option<f64>,
    anees_interval: Option<[f64; 2]>,
    anis: f64,
    anis_interval: [f64; 2],
    nees_fraction_in_bounds: Option<f64>,
    nis_fraction_in_bounds: f64,
}

/// A seed as a TOML value: TOML integers are 64-bit signed, so larger seeds are written as
/// strings rather than lost.
fn seed_value(seed: u64) -> toml::Value {
    i64::try_from(seed).map_or_else(
        |_| toml::Value::String(seed.to_string()),
        toml::Value::Integer,
    )
}

fn rows(m: &nalgebra::DMatrix<f64>) -> Vec<Vec<f64>> {
    (0..m.nrows())
        .map(|i| m.row(i).iter().copied().collect())
        .collect()
}

/// Longest float literal kept as the TOML writer prints it: a 17-digit value with up to a
/// dozen leading zeros (1e-12). Longer ones are hundreds of digits (1e100, 1e-300).
const LONGEST_PLAIN_FLOAT: usize = 32;

/// `toml` with every float literal longer than [`LONGEST_PLAIN_FLOAT`] characters rewritten
/// in scientific notation (the TOML writer prints floats without an exponent, so the ANEES
/// of a diverging filter came out as a hundred digits). `{:e}` is the shortest form that
/// reads back as the same `f64`, so the values are unchanged. Strings are left alone.
fn compact_floats(toml: &str) -> String {
    let mut out = String::with_capacity(toml.len());
    let mut chars = toml.char_indices().peekable();
    let mut quote: Option<char> = None;
    while let Some((i, c)) = chars.next() {
        match quote {
            Some(q) => {
                out.push(c);
                if c == '\\' && q == '"' {
                    if let Some((_, e)) = chars.next() {
                        out.push(e);
                    }
                } else if c == q {
                    quote = None;
                }
            }
            None if c == '"' || c == '\'' => {
                quote = Some(c);
                out.push(c);
            }
            None if c == '-' || c.is_ascii_digit() => {
                let mut end = i + c.len_utf8();
                while let Some(&(j, d)) = chars.peek() {
                    if d.is_ascii_alphanumeric() || "._+-".contains(d) {
                        end = j + d.len_utf8();
                        chars.next();
                    } else {
                        break;
                    }
                }
                let token = &toml[i..end];
                match token.parse::<f64>() {
                    Ok(v) if token.len() > LONGEST_PLAIN_FLOAT && v.is_finite() => {
                        out.push_str(&format!("{v:e}"));
                    }
                    _ => out.push_str(token),
                }
            }
            None => out.push(c),
        }
    }
    out
}

/// A config holding parameter values `theta` estimated from measurements (not tuned by the
/// Monte Carlo search), with `provenance` saying how: `autotune check PROBLEM --config FILE`
/// reads it like a tuned config.
pub fn estimated_config_toml(
    experiment: &dyn Experiment,
    theta: &[f64],
    provenance: toml::Table,
) -> String {
    let info = experiment.info();
    let cov = experiment.covariances(theta);
    let cfg = TunedConfig {
        problem: info.name.clone(),
        q: cov.as_ref().map(|c| rows(&c.Q)),
        r: cov.as_ref().map(|c| rows(&c.R)),
        params: experiment
            .params()
            .names()
            .into_iter()
            .map(str::to_string)
            .zip(theta.iter().copied())
            .collect(),
        bounds: None,
        provenance: Some(provenance),
    };
    let body = compact_floats(&toml::to_string(&cfg).expect("a config serializes"));
    format!(
        "# Estimated by autotune {} from measurements, for {}.\n# Check it with: {} --config <this file>\n{body}",
        env!("CARGO_PKG_VERSION"),
        info.source.label(),
        info.source.check_command()
    )
}

/// A tuned config whose run did not confirm: the same file as [`tuned_config_toml`] behind
/// a comment block that says why it is rejected and gives the ranked explanations (TOML
/// comments, so `check --config` still reads it to reproduce the finding).
pub fn rejected_config_toml(
    experiment: &dyn Experiment,
    result: &TuneResult,
    explanations: &[crate::explain::Explanation],
) -> String {
    let mut head = format!(
        "# REJECTED by autotune {}: this tuning did not make the filter consistent; do not apply these values.\n",
        env!("CARGO_PKG_VERSION")
    );
    let lines =
        crate::report::check::advice::family_finding(result, explanations).unwrap_or_else(|| {
            vec![format!(
                "the search ended {} (confirmation: {})",
                format!("{:?}", result.status).to_lowercase(),
                result.confirmation.text()
            )]
        });
    for l in lines {
        head.push_str("# ");
        head.push_str(&l.replace('\n', " "));
        head.push('\n');
    }
    head.push('\n');
    head + &tuned_config_toml(experiment, result)
}

/// The tuned config of a tuning run, as TOML text with a comment header.
pub fn tuned_config_toml(experiment: &dyn Experiment, result: &TuneResult) -> String {
    let info = experiment.info();
    let cov = experiment.covariances(&result.tuned);
    let a = &result.after;
    let prov = Provenance {
        autotune_version: env!("CARGO_PKG_VERSION"),
        problem_file: info.source.label(),
        problem_sha256: info.source.sha256().map(str::to_string),
        status: format!("{:?}", result.status).to_lowercase(),
        scoring: format!("{:?}", result.scoring).to_lowercase(),
        search_seed: seed_value(result.search_seed),
        confirm_seed: seed_value(result.confirm_seed),
        runs: result.runs,
        steps: result.steps,
        alpha: result.alpha,
        objective: result.objective_final.total,
        evaluations: result.evaluations,
        diverged_evaluations: result.diverged_evaluations,
        confirmation: Confirmation {
            seeds: result.confirmation.seeds,
            passed: result.confirmation.passed,
            band_low: result.confirmation.band_low,
            recorded: result.confirmation.recorded,
            verdict: a.verdict.label().to_string(),
            anees: a.nees.as_ref().map(|s| s.time_average),
            anees_interval: a
                .nees
                .as_ref()
                .map(|s| [s.interval.lower, s.interval.upper]),
            anis: a.nis.time_average,
            anis_interval: [a.nis.interval.lower, a.nis.interval.upper],
            nees_fraction_in_bounds: a.nees.as_ref().map(|s| s.fraction_in_bounds),
            nis_fraction_in_bounds: a.nis.fraction_in_bounds,
        },
    };
    let cfg = TunedConfig {
        problem: info.name.clone(),
        q: cov.as_ref().map(|c| rows(&c.Q)),
        r: cov.as_ref().map(|c| rows(&c.R)),
        params: result
            .names
            .iter()
            .cloned()
            .zip(result.tuned.iter().copied())
            .collect(),
        bounds: (!result.widened.is_empty()).then(|| {
            result
                .widened
                .iter()
                .map(|w| (result.names[w.param].clone(), [w.to.0, w.to.1]))
                .collect()
        }),
        provenance: Some(toml::Table::try_from(&prov).expect("provenance is a plain table")),
    };
    let body = compact_floats(&toml::to_string(&cfg).expect("a tuned config serializes"));
    format!(
        "# Tuned by autotune {} from {}.\n# Check it with: {} --config <this file>\n{body}",
        env!("CARGO_PKG_VERSION"),
        info.source.label(),
        info.source.check_command()
    )
}

impl TunedConfig {
    /// Read a tuned config for `experiment` and map its values onto the experiment's
    /// parameters: every parameter must be given, and nothing else; a `Q` or `R` the config
    /// carries must be what those values give (within 1e-9 of the matrix's largest entry),
    /// so that a config edited by hand, or tuned for another version of the problem, is
    /// not read as something it is not.
    pub fn load_values(path: &Path, experiment: &dyn Experiment) -> Result<Vec<f64>, FileError> {
        let text = read_text(path)?;
        let cfg: TunedConfig = parse_toml(&text, path)?;
        let values = cfg.values(path, &experiment.info().name, experiment.params())?;
        if cfg.q.is_some() || cfg.r.is_some() {
            let cov = experiment.covariances(&values);
            for (field, given, expected) in [
                ("Q", &cfg.q, cov.as_ref().map(|c| &c.Q)),
                ("R", &cfg.r, cov.as_ref().map(|c| &c.R)),
            ] {
                if let (Some(given), Some(expected)) = (given, expected) {
                    same_matrix(given, expected)
                        .map_err(|m| FileError::new(path, field, m.to_string()))?;
                }
            }
        }
        Ok(values)
    }

    /// The parameter values in `space`'s order, checked against it.
    fn values(
        &self,
        path: &Path,
        problem_name: &str,
        space: &ParamSpace,
    ) -> Result<Vec<f64>, FileError> {
        let err = |field: String, message: String| FileError::new(path, field, message);
        if self.problem != problem_name {
            return Err(err(
                "problem".into(),
                // Escaped: the name is whatever the file says, newlines included, and the
                // error must stay on one line.
                format!(
                    "this config was tuned for '{}', not '{problem_name}'",
                    self.problem.escape_debug()
                ),
            ));
        }
        let mut values = space.values();
        for (name, &v) in &self.params {
            let Some(i) = space.index(name) else {
                return Err(err(
                    format!("params.{name}"),
                    format!(
                        "the problem has no parameter '{name}' (it has: {})",
                        space.names().join(", ")
                    ),
                ));
            };
            if !(v.is_finite() && v > 0.0) {
                return Err(err(
                    format!("params.{name}"),
                    format!("{v} must be a finite number > 0"),
                ));
            }
            values[i] = v;
        }
        for p in &space.params {
            if !self.params.contains_key(&p.name) {
                return Err(err(format!("params.{}", p.name), "missing".into()));
            }
        }
        for (name, &[lower, upper]) in self.bounds.iter().flatten() {
            let field = format!("bounds.{name}");
            let Some(i) = space.index(name) else {
                return Err(err(
                    field,
                    format!(
                        "the problem has no parameter '{name}' (it has: {})",
                        space.names().join(", ")
                    ),
                ));
            };
            if !(lower.is_finite() && upper.is_finite() && 0.0 < lower && lower < upper) {
                return Err(err(
                    field,
                    format!("[{lower}, {upper}] must satisfy 0 < lower < upper"),
                ));
            }
            if !(lower..=upper).contains(&values[i]) {
                return Err(err(
                    field,
                    format!(
                        "[{lower}, {upper}] does not hold params.{name} = {}",
                        values[i]
                    ),
                ));
            }
        }
        Ok(values)
    }
}

/// How a config's stored matrix differs from what its parameters give.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
enum MatrixMismatch {
    /// Another shape than the parameters' matrix.
    #[error(
        "is not {rows}×{cols}, the shape this problem's parameters give (remove Q and R, or tune again)"
    )]
    Shape {
        /// The parameters' matrix's rows.
        rows: usize,
        /// Its columns.
        cols: usize,
    },
    /// An entry off by more than the tolerance.
    #[error(
        "[{row}][{col}] = {given:e}, but the parameters give {expected:e} (remove Q and R, or tune again)"
    )]
    Entry {
        /// Row index.
        row: usize,
        /// Column index.
        col: usize,
        /// The stored value.
        given: f64,
        /// The parameters' value.
        expected: f64,
    },
}

/// Whether the rows `given` hold `expected`, to 1e-9 of its largest entry; the error says
/// where they differ.
fn same_matrix(
    given: &[Vec<f64>],
    expected: &nalgebra::DMatrix<f64>,
) -> Result<(), MatrixMismatch> {
    let (rows, cols) = expected.shape();
    if given.len() != rows || given.iter().any(|r| r.len() != cols) {
        return Err(MatrixMismatch::Shape { rows, cols });
    }
    let tol = 1e-9 * expected.amax().max(f64::MIN_POSITIVE);
    for (i, row) in given.iter().enumerate() {
        for (j, &v) in row.iter().enumerate() {
            let e = expected[(i, j)];
            if (v - e).abs() > tol {
                return Err(MatrixMismatch::Entry {
                    row: i,
                    col: j,
                    given: v,
                    expected: e,
                });
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn long_floats_become_scientific_and_read_back_the_same() {
        let mut t = toml::Table::new();
        for (k, v) in [
            ("big", 1e100),
            ("tiny", -1.5e-300),
            ("plain", 0.125),
            ("e12", 2.1e-12),
        ] {
            t.insert(k.into(), toml::Value::Float(v));
        }
        t.insert("s".into(), toml::Value::String(format!("{}", 1e100)));
        let text = compact_floats(&toml::to_string(&t).unwrap());
        assert!(text.contains("big = 1e100"), "{text}");
        assert!(text.contains("tiny = -1.5e-300"), "{text}");
        assert!(text.contains("plain = 0.125"), "{text}");
        assert!(text.contains("e12 = 0.0000000000021"), "{text}");
        let back: toml::Table = text.parse().unwrap();
        assert_eq!(back, t, "values and the string survive");
    }
}

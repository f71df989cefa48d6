//! Tuned configs written: the parameter values (and the Q and R they give) that `autotune
//! check --config` applies on top of a problem file, with the provenance of the tuning run
//! (or of the estimate) that found them. `crate::problem` reads them back.

use serde::Serialize;

pub use crate::problem::TunedConfig;

use crate::experiment::Experiment;
use crate::tune::TuneResult;

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
    let lines = crate::report::advice::family_finding(result, explanations).unwrap_or_else(|| {
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

//! The tuner's two choices of method, as a problem file, a flag or a setter names them: how
//! candidates are scored ([`Scoring`]) and which local search runs ([`LocalSearch`]).

use serde::Serialize;

use crate::input::SettingError;

/// How candidates are scored during the search.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum Scoring {
    /// Exact expectations where the experiment allows them, Monte Carlo otherwise.
    #[default]
    Auto,
    /// Exact expected statistics (a linear filter with the truth's F and H).
    Exact,
    /// Monte Carlo with common random numbers.
    #[value(name = "monte_carlo", alias = "monte-carlo")]
    MonteCarlo,
}

/// The local search that refines the global stage's best points.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum LocalSearch {
    /// Nelder–Mead with a wide simplex (0.7 in log units, a factor 2), restarted with a
    /// small one to polish. Derivative-free and exploratory: it can leave a shallow local
    /// minimum. Suits problems with a few free parameters.
    #[default]
    #[value(alias = "nelder_mead", alias = "nelder-mead")]
    Simplex,
    /// Levenberg–Marquardt on the objective's residual vector (J is a sum of squares) with
    /// a finite-difference Jacobian: d + 1 evaluations an iteration, converging in a
    /// handful. Suits many free parameters of an expensive Monte Carlo, where a simplex
    /// needs hundreds of evaluations; it stays in the basin it starts in, so it relies on
    /// the global stage and several starts.
    #[value(
        name = "gauss_newton",
        alias = "gauss-newton",
        alias = "levenberg_marquardt",
        alias = "levenberg-marquardt"
    )]
    GaussNewton,
}

/// `s` as one of `E`'s names or aliases, or an error for `setting` listing the names.
fn parse_name<E: clap::ValueEnum>(setting: &str, what: &str, s: &str) -> Result<E, SettingError> {
    E::from_str(s, false).map_err(|_| {
        let known: Vec<String> = E::value_variants()
            .iter()
            .filter_map(|v| v.to_possible_value().map(|p| p.get_name().to_string()))
            .collect();
        SettingError::new(
            setting,
            format!("unknown {what} '{s}' (known: {})", known.join(", ")),
        )
    })
}

impl Scoring {
    /// Parse `auto`, `exact` or `monte_carlo` (also `monte-carlo`).
    pub fn from_name(s: &str) -> Result<Scoring, SettingError> {
        parse_name("scoring", "scoring", s)
    }
}

impl LocalSearch {
    /// Parse `simplex` (also `nelder_mead`) or `gauss_newton` (also `levenberg_marquardt`).
    pub fn from_name(s: &str) -> Result<LocalSearch, SettingError> {
        parse_name("local", "local search", s)
    }
}

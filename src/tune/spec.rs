//! The tuner's settings as a person gives them, defined once: a problem file's `[tune]`
//! table and the `tune` command's flags are the same fields of [`TuneSpec`] (a TOML key
//! `max_evals` is the flag `--max-evals`), checked by the same setters of
//! [`TuneSettings`] when [`TuneSpec::apply`] lays them over defaults. A refusal names the
//! field; the problem loader prefixes it with `tune.`, the command line spells it as its
//! flag ([`TuneSpec::flag`]).

use serde::{Deserialize, Deserializer};

use super::choices::{LocalSearch, Scoring};
use super::settings::TuneSettings;
use crate::input::SettingError;

/// Settings for `autotune tune`, each optional: unset ones keep the value underneath (the
/// defaults under a problem file's `[tune]`, the file's under the command line's).
#[derive(Debug, Clone, Default, PartialEq, Deserialize, clap::Args)]
#[serde(deny_unknown_fields)]
pub struct TuneSpec {
    /// Set an objective weight, NAME=VALUE (mean, interval, per_step, components,
    /// whiteness, shape, bias; repeatable).
    #[serde(default, deserialize_with = "weight_table")]
    #[arg(long = "weight", value_name = "NAME=VALUE")]
    pub weights: Vec<String>,
    /// Evaluation budget of the search.
    #[arg(long, allow_negative_numbers = true)]
    pub max_evals: Option<i64>,
    /// Wall-time budget of the search, s.
    #[arg(long, allow_negative_numbers = true)]
    pub max_seconds: Option<f64>,
    /// Local searches started from the best points of the global stage (default 3).
    #[arg(long, allow_negative_numbers = true)]
    pub starts: Option<i64>,
    /// Quasi-random points of the global stage per free parameter (default 16).
    #[arg(long, allow_negative_numbers = true)]
    pub global_points: Option<i64>,
    /// How candidates are scored: auto, exact or monte_carlo.
    #[arg(long, value_parser = crate::input::OneOf::<Scoring>::names())]
    pub scoring: Option<String>,
    /// Local search from the best global points: simplex (Nelder–Mead) or gauss_newton
    /// (Levenberg–Marquardt, for many expensive parameters).
    #[arg(long, value_parser = crate::input::OneOf::<LocalSearch>::names())]
    pub local: Option<String>,
    /// Score innovations only (ground truth not trusted).
    #[arg(long, num_args = 0, default_missing_value = "true")]
    pub nis_only: Option<bool>,
    /// Runs per Monte Carlo evaluation during the search (default 4 N).
    #[arg(long, allow_negative_numbers = true)]
    pub search_runs: Option<i64>,
    /// Runs of the final refinement under Monte Carlo scoring (default 4 × search runs).
    #[arg(long, allow_negative_numbers = true)]
    pub refine_runs: Option<i64>,
    /// Number of fresh seeds the tuned filter is confirmed on (default 20; with
    /// --measurements the record is one draw, confirmed once).
    #[arg(long, allow_negative_numbers = true)]
    pub confirm_seeds: Option<i64>,
    /// Seed of the first confirmation run (default: derived from the search's seed).
    #[arg(long, allow_negative_numbers = true)]
    pub confirm_seed: Option<u64>,
}

/// `[tune.weights]`, a table of numbers by name, as the flag's NAME=VALUE entries (in the
/// file's order; a number prints back exactly).
fn weight_table<'de, D: Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    let table = indexmap::IndexMap::<String, f64>::deserialize(d)?;
    Ok(table.into_iter().map(|(k, v)| format!("{k}={v}")).collect())
}

impl TuneSpec {
    /// `base` with every setting given here laid over it, each through its setter. A
    /// refusal names the field (`max_evals`, `weights.mean`).
    pub fn apply(&self, base: TuneSettings) -> Result<TuneSettings, SettingError> {
        let mut weights = Vec::with_capacity(self.weights.len());
        for kv in &self.weights {
            let (name, value) = kv
                .split_once('=')
                .ok_or_else(|| SettingError::new("weights", format!("'{kv}' is not NAME=VALUE")))?;
            let v: f64 = value.trim().parse().map_err(|_| {
                SettingError::new("weights", format!("{name}: '{value}' is not a number"))
            })?;
            weights.push((name.trim(), v));
        }
        let mut s = if weights.is_empty() {
            base
        } else {
            base.with_named_weights(weights)?
        };
        if let Some(n) = self.max_evals {
            s = s.with_max_evals(n)?;
        }
        if let Some(v) = self.max_seconds {
            s = s.with_max_seconds(v)?;
        }
        if let Some(n) = self.starts {
            s = s.with_starts(n)?;
        }
        if let Some(b) = self.nis_only {
            s = s.with_nis_only(b);
        }
        if let Some(n) = self.search_runs {
            s = s.with_search_runs(n)?;
        }
        if let Some(n) = self.refine_runs {
            s = s.with_refine_runs(Some(n))?;
        }
        if let Some(n) = self.confirm_seeds {
            s = s.with_confirm_seeds(n)?;
        }
        if let Some(n) = self.global_points {
            s = s.with_global_points(n)?;
        }
        if let Some(l) = &self.local {
            s = s.with_local(LocalSearch::from_name(l)?);
        }
        if let Some(x) = &self.scoring {
            s = s.with_scoring(Scoring::from_name(x)?);
        }
        if let Some(seed) = self.confirm_seed {
            s = s.with_confirm_seed(Some(seed));
        }
        Ok(s)
    }

    /// The flag that gives `setting` (a field name as a refusal names it): `max_evals` →
    /// `--max-evals`, `weights.mean` → `--weight`.
    pub fn flag(setting: &str) -> String {
        if setting == "weights" || setting.starts_with("weights.") {
            return "--weight".into();
        }
        format!("--{}", setting.replace('_', "-"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(toml_text: &str) -> TuneSpec {
        toml::from_str(toml_text).unwrap()
    }

    #[test]
    fn a_file_and_the_flags_give_the_same_settings() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Cli {
            #[command(flatten)]
            spec: TuneSpec,
        }
        let file = spec(
            "max_evals = 77\nmax_seconds = 9.5\nstarts = 2\nglobal_points = 5\n\
             scoring = \"monte_carlo\"\nlocal = \"gauss_newton\"\nnis_only = true\n\
             search_runs = 40\nrefine_runs = 80\nconfirm_seeds = 7\nconfirm_seed = 99\n\
             [weights]\nmean = 0.25\nshape = 2.5\n",
        );
        let flags = Cli::parse_from([
            "t",
            "--max-evals",
            "77",
            "--max-seconds",
            "9.5",
            "--starts",
            "2",
            "--global-points",
            "5",
            "--scoring",
            "monte_carlo",
            "--local",
            "gauss_newton",
            "--nis-only",
            "--search-runs",
            "40",
            "--refine-runs",
            "80",
            "--confirm-seeds",
            "7",
            "--confirm-seed",
            "99",
            "--weight",
            "mean=0.25",
            "--weight",
            "shape=2.5",
        ])
        .spec;
        assert_eq!(file, flags);
        let s = file.apply(TuneSettings::default()).unwrap();
        assert_eq!(s.max_evals(), 77);
        assert_eq!(s.max_seconds(), 9.5);
        assert_eq!(s.starts(), 2);
        assert_eq!(s.global_points(), 5);
        assert_eq!(s.scoring(), Scoring::MonteCarlo);
        assert_eq!(s.local(), LocalSearch::GaussNewton);
        assert!(s.local_is_set() && s.nis_only());
        assert_eq!(s.search_runs(), Some(40));
        assert_eq!(s.refine_runs(), Some(80));
        assert_eq!(s.confirm_seeds(), 7);
        assert_eq!(s.confirm_seed(), Some(99));
        let w = TuneSettings::default()
            .with_named_weights([("shape", 2.5), ("mean", 0.25)])
            .unwrap()
            .weights();
        assert_eq!(s.weights(), w);
    }

    #[test]
    fn unset_fields_keep_what_is_underneath() {
        let base = TuneSettings::default().with_max_evals(5).unwrap();
        let s = spec("starts = 4").apply(base.clone()).unwrap();
        assert_eq!(s.max_evals(), 5);
        assert_eq!(s.starts(), 4);
        assert_eq!(TuneSpec::default().apply(base.clone()).unwrap(), base);
        // A flag that is absent does not turn the file's nis_only off.
        let nis = spec("nis_only = true")
            .apply(TuneSettings::default())
            .unwrap();
        assert!(TuneSpec::default().apply(nis).unwrap().nis_only());
    }

    #[test]
    fn refusals_name_the_field_and_its_flag() {
        for (text, setting, flag) in [
            ("max_evals = 0", "max_evals", "--max-evals"),
            ("max_seconds = -1.0", "max_seconds", "--max-seconds"),
            ("starts = 0", "starts", "--starts"),
            ("global_points = 1001", "global_points", "--global-points"),
            ("search_runs = 0", "search_runs", "--search-runs"),
            ("refine_runs = 0", "refine_runs", "--refine-runs"),
            ("confirm_seeds = 1", "confirm_seeds", "--confirm-seeds"),
            ("local = \"x\"", "local", "--local"),
            ("scoring = \"x\"", "scoring", "--scoring"),
            ("weights = { colour = 1.0 }", "weights.colour", "--weight"),
        ] {
            let e = spec(text).apply(TuneSettings::default()).unwrap_err();
            assert_eq!(e.setting, setting, "{text}");
            assert_eq!(TuneSpec::flag(&e.setting), flag, "{text}");
        }
        let bad = TuneSpec {
            weights: vec!["mean".into()],
            ..TuneSpec::default()
        };
        let e = bad.apply(TuneSettings::default()).unwrap_err();
        assert_eq!(
            (e.setting.as_str(), e.message.as_str()),
            ("weights", "'mean' is not NAME=VALUE")
        );
    }
}

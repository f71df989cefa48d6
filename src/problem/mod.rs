//! Problem files: the TOML schema ([`spec`]), validation with errors that name the file and
//! field, and construction of the [`Experiment`] the file describes (a linear truth and
//! Kalman filter, or a catalog model) with its `[tune]` settings.

mod catalog;
mod covariance;
mod external;
mod linear;
pub mod spec;
mod tuned;
mod validate;

use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::experiment::{
    Covariances, Definition, Experiment, ExperimentError, Info, LinearExperiment, RunOptions,
    Source,
};
use crate::external::ExternalExperiment;
use crate::input::{FileError, SettingError, parse_toml};
use crate::montecarlo::{Engine, McConfig};
use crate::params::{ParamDef, ParamSpace, Target};
use crate::stats::Accumulator;
use crate::tune::TuneSettings;
use crate::userfile::read_text;
pub use spec::ProblemSpec;
pub use tuned::TunedConfig;
use validate::{VResult, Validator};

/// Which kind of system a problem file describes: the section that defines it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProblemKind {
    /// `[truth]` and `[filter]` matrices: a linear truth and Kalman filter.
    Linear,
    /// `[model]`: a named model of the catalog.
    Catalog,
    /// `[external]`: a worker program.
    External,
}

impl ProblemKind {
    /// The file's section that defines this kind (`truth`, `model`, `external`), for errors
    /// that must name where the obstacle is.
    pub fn field(self) -> &'static str {
        match self {
            ProblemKind::Linear => "truth",
            ProblemKind::Catalog => "model",
            ProblemKind::External => "external",
        }
    }

    /// How a sentence names the kind: "a catalog model (model)".
    pub fn describe(self) -> &'static str {
        match self {
            ProblemKind::Linear => "a linear problem ([truth] and [filter] matrices)",
            ProblemKind::Catalog => "a catalog model ([model])",
            ProblemKind::External => "an external worker ([external])",
        }
    }
}

/// A validated problem file: the experiment it describes, and its `[tune]` settings. It is
/// an [`Experiment`] itself (delegating to the one the file describes); the layers above
/// see that experiment and nothing more concrete.
pub struct Problem {
    experiment: Built,
    kind: ProblemKind,
    /// Sample period between filter steps, s.
    pub dt: f64,
    /// The file's `[tune]` section, validated (defaults where absent).
    pub tune: TuneSettings,
}

/// What a problem file built: a worker program (kept as such, since it can also replay a
/// record), or any other experiment.
enum Built {
    Worker(Box<ExternalExperiment>),
    Other(Box<dyn Experiment>),
}

impl std::fmt::Debug for Problem {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Problem")
            .field("name", &self.name())
            .field("kind", &self.kind)
            .field("dt", &self.dt)
            .field("tune", &self.tune)
            .finish_non_exhaustive()
    }
}

impl Problem {
    /// Read and validate a problem file.
    pub fn load(path: &Path) -> Result<Problem, FileError> {
        Problem::from_toml(&read_text(path)?, path)
    }

    /// Validate problem-file text; `path` names it in errors.
    pub fn from_toml(text: &str, path: &Path) -> Result<Problem, FileError> {
        let spec = parse_toml::<ProblemSpec>(text, path)?;
        Validator { file: path }.problem(spec, sha256_hex(text.as_bytes()))
    }

    /// The experiment the file describes.
    pub fn experiment(&self) -> &dyn Experiment {
        match &self.experiment {
            Built::Worker(w) => w.as_ref(),
            Built::Other(e) => e.as_ref(),
        }
    }

    /// The experiment the file describes, owned.
    pub fn into_experiment(self) -> Box<dyn Experiment> {
        match self.experiment {
            Built::Worker(w) => w,
            Built::Other(e) => e,
        }
    }

    /// The worker program of an `[external]` problem, which can also replay its filter
    /// over a record ([`crate::external::WorkerReplay`]).
    pub fn worker(&self) -> Option<&ExternalExperiment> {
        match &self.experiment {
            Built::Worker(w) => Some(w),
            Built::Other(_) => None,
        }
    }

    /// Which section defines the system.
    pub fn kind(&self) -> ProblemKind {
        self.kind
    }

    /// The problem's name (from the file, or its stem).
    pub fn name(&self) -> &str {
        &self.info().name
    }

    /// The file it was read from.
    pub fn path(&self) -> PathBuf {
        match &self.info().source {
            Source::File { path, .. } => path.clone(),
            Source::Program { name } => PathBuf::from(name),
            Source::Records { files } => files.first().cloned().unwrap_or_default(),
        }
    }
}

impl Experiment for Problem {
    fn definition(&self) -> &Definition {
        self.experiment().definition()
    }

    fn monte_carlo_with(
        &self,
        theta: &[f64],
        mc: &McConfig,
        run: RunOptions<'_>,
    ) -> Result<Accumulator, ExperimentError> {
        self.experiment().monte_carlo_with(theta, mc, run)
    }
}

impl crate::experiment::Structure for Problem {
    fn supports(&self, engine: Engine) -> bool {
        self.experiment().supports(engine)
    }

    fn expected(&self, theta: &[f64], mc: &McConfig) -> Option<Accumulator> {
        self.experiment().expected(theta, mc)
    }

    fn target(&self, i: usize) -> Option<Target> {
        self.experiment().target(i)
    }

    fn covariances(&self, theta: &[f64]) -> Option<Covariances> {
        self.experiment().covariances(theta)
    }

    fn truth_values(&self) -> Option<Vec<f64>> {
        self.experiment().truth_values()
    }

    fn blocks(&self) -> Option<Vec<crate::experiment::Block>> {
        self.experiment().blocks()
    }

    fn linear(&self) -> Option<&LinearExperiment> {
        self.experiment().linear()
    }
}

impl crate::experiment::HeldAsCode for Problem {
    fn monte_carlo_corrected(
        &self,
        theta: &[f64],
        mc: &McConfig,
        options: RunOptions<'_>,
        correction: &crate::filter::Correction,
    ) -> Option<Result<Accumulator, ExperimentError>> {
        self.experiment()
            .monte_carlo_corrected(theta, mc, options, correction)
    }

    fn innovation_scales(&self, theta: &[f64], mc: &McConfig) -> Option<Vec<f64>> {
        self.experiment().innovation_scales(theta, mc)
    }

    fn replay_filter(&self, theta: &[f64]) -> Option<Box<dyn crate::filter::Filter + '_>> {
        self.experiment().replay_filter(theta)
    }

    fn simulation_truth(&self) -> Option<&dyn crate::model::TruthModel> {
        self.experiment().simulation_truth()
    }
}

impl crate::experiment::Sampling for Problem {
    fn seed_free(&self) -> bool {
        self.experiment().seed_free()
    }

    fn splits_runs(&self) -> bool {
        self.experiment().splits_runs()
    }

    fn truth_reuse(&self, since: crate::montecarlo::TapeUsage) -> crate::experiment::TruthReuse {
        self.experiment().truth_reuse(since)
    }

    fn tape_usage(&self) -> crate::montecarlo::TapeUsage {
        self.experiment().tape_usage()
    }
}

/// SHA-256 of bytes as lowercase hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

impl Validator<'_> {
    fn problem(&self, s: ProblemSpec, sha256: String) -> VResult<Problem> {
        let dt = match s.dt {
            // A worker keeps its own time step: autotune never sends dt, so a value here
            // would be a setting that silently does nothing.
            Some(_) if s.external.is_some() => {
                return self.err(
                    "dt",
                    "an [external] problem's time step is its worker's own (autotune neither uses nor sends it): leave dt out",
                );
            }
            Some(dt) => self.finite("dt", dt)?,
            None if s.external.is_some() => 1.0,
            None => return self.err("dt", "missing: the sample period between steps, s"),
        };
        if dt <= 0.0 {
            return self.err("dt", format!("{dt} must be > 0 (seconds per step)"));
        }
        let mc = self.montecarlo(&s.montecarlo)?;
        let name = s.name.clone().unwrap_or_else(|| {
            self.file
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "problem".into())
        });
        // The name becomes part of output paths (tuned/<name>.toml).
        if name.is_empty()
            || !name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-')
        {
            let field = if s.name.is_some() {
                "name"
            } else {
                "name (from the file name)"
            };
            return self.err(
                field,
                format!("'{name}' must be letters, digits, _ and - only"),
            );
        }
        let info = Info {
            name,
            description: s.description.clone().unwrap_or_default(),
            source: Source::File {
                path: self.file.to_path_buf(),
                sha256,
            },
        };
        // The one place the kinds of system are told apart: each section builds its
        // experiment, and everything after sees only the trait.
        let (kind, experiment): (ProblemKind, Built) =
            match (&s.external, &s.truth, &s.filter, &s.model) {
                (Some(_), t, f, m) if t.is_some() || f.is_some() || m.is_some() => {
                    return self.err(
                        "external",
                        "give [external] alone, without [truth], [filter] or [model]",
                    );
                }
                (Some(ext), ..) => (
                    ProblemKind::External,
                    Built::Worker(Box::new(self.external_problem(&s, ext, info, mc)?)),
                ),
                (None, None, None, Some(model)) => (
                    ProblemKind::Catalog,
                    Built::Other(Box::new(self.catalog_problem(&s, model, info, mc)?)),
                ),
                (None, t, _, Some(_)) => {
                    let which = if t.is_some() { "truth" } else { "filter" };
                    return self.err(
                        which,
                        "give either [model] (a named model) or [truth] and [filter], not both",
                    );
                }
                (None, Some(t), Some(f), None) => (
                    ProblemKind::Linear,
                    Built::Other(Box::new(self.linear_problem(&s, t, f, info, mc)?)),
                ),
                (None, None, _, None) => {
                    return self.err(
                        "truth",
                        "missing: give [truth] and [filter], or [model] with a catalog name",
                    );
                }
                (None, Some(_), None, None) => return self.err("filter", "missing"),
            };
        let tune = self.tune_settings(&s.tune)?;
        Ok(Problem {
            experiment,
            kind,
            dt,
            tune,
        })
    }

    /// `[montecarlo]` as a checked [`McConfig`].
    fn montecarlo(&self, m: &spec::MonteCarloSpec) -> VResult<McConfig> {
        let at = |e: SettingError| FileError::from_setting(self.file, "montecarlo.", e);
        let mc = McConfig::new(m.runs, m.steps)
            .and_then(|mc| mc.with_alpha(m.alpha))
            .map_err(at)?
            .with_seed(m.seed)
            .with_gate(m.gate);
        match m.lags {
            Some(l) => mc.with_lags(l).map_err(at),
            None => Ok(mc),
        }
    }

    /// `[tune]` laid over the defaults through the setters.
    fn tune_settings(&self, t: &crate::tune::TuneSpec) -> VResult<TuneSettings> {
        t.apply(TuneSettings::default())
            .map_err(|e| FileError::from_setting(self.file, "tune.", e))
    }

    /// `[params]` in file order, each checked by [`ParamDef::validate`].
    fn params(&self, spec: &indexmap::IndexMap<String, spec::ParamSpec>) -> VResult<ParamSpace> {
        let mut params = Vec::with_capacity(spec.len());
        for (name, p) in spec {
            let lower = p.lower.unwrap_or(p.value / 1e4);
            let upper = p.upper.unwrap_or(p.value * 1e4);
            let def = ParamDef {
                name: name.clone(),
                value: p.value,
                lower,
                upper,
                fixed: p.fixed,
                unit: p.unit.clone(),
                about: p.about.clone(),
            };
            def.validate().map_err(|e| {
                FileError::from_setting(self.file, "", e.within(&format!("params.{name}")))
            })?;
            params.push(def);
        }
        Ok(ParamSpace { params })
    }
}

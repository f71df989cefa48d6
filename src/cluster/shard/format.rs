//! The shard file's contents: its settings, its chunks, the head read before its sums,
//! and why a merge refuses it.

use std::path::{Path, PathBuf};

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde::{Deserialize, Serialize};

use crate::cluster::SumsShape;
use crate::experiment::Experiment;
use crate::input::SettingError;
use crate::montecarlo::{Engine, McConfig, Share};
use crate::stats::{Accumulator, GateMode};
/// The `format` field of a shard file.
pub const FORMAT: &str = "autotune-shard";
/// The version of the shard format this autotune writes and reads.
pub const VERSION: u32 = 1;
/// Largest shard file `autotune merge` reads, bytes: 4 GiB (a chunk of T steps takes about
/// 100 T bytes for a few components, so 10⁸ run-steps per shard).
pub const MAX_FILE: u64 = 4 << 30;

/// A number as a shard file carries it: its value for people, its IEEE bits (hex) for the
/// merge, which compares and uses the bits.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Number {
    /// The value, as JSON prints it.
    pub value: serde_json::Number,
    /// `f64::to_bits`, 16 hex digits.
    pub bits: String,
}

impl Number {
    pub(super) fn of(x: f64) -> Number {
        Number {
            value: serde_json::Number::from_f64(x).unwrap_or_else(|| 0.into()),
            bits: format!("{:016x}", x.to_bits()),
        }
    }

    pub(super) fn get(&self) -> Option<f64> {
        u64::from_str_radix(&self.bits, 16).ok().map(f64::from_bits)
    }
}

/// What makes a shard's sums: shards merge only when all of this is the same.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardSettings {
    /// The experiment's name.
    pub problem: String,
    /// The problem file as given to `check` (`merge` reads it again for the reports).
    pub file: PathBuf,
    /// SHA-256 of the problem file's bytes, lowercase hex.
    pub sha256: String,
    /// The parameter values the filter ran with, by name.
    pub params: Vec<(String, Number)>,
    /// Monte Carlo runs N.
    pub runs: usize,
    /// Steps per run T.
    pub steps: usize,
    /// Base seed.
    pub seed: u64,
    /// Significance level α.
    pub alpha: Number,
    /// Whiteness lags.
    pub lags: usize,
    /// The gate: `full` or `mean`.
    pub gate: String,
    /// The engine path asked for: `auto`, `linear` or `generic`.
    pub engine: String,
    /// Judged by NIS alone.
    pub nis_only: bool,
    /// State components of the sums.
    pub n_x: usize,
    /// Measurement components of the sums.
    pub n_z: usize,
}

/// Which share a file holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardIndex {
    /// 0-based.
    pub index: usize,
    /// Shards in all.
    pub count: usize,
}

/// One chunk's sums in a shard file.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardChunk {
    /// The chunk: runs `64 chunk .. 64 chunk + 64`.
    pub chunk: usize,
    /// Its sums in autotune's sums format, base64.
    pub sums: String,
}

/// A shard file's contents.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardFile {
    /// [`FORMAT`].
    pub format: String,
    /// [`VERSION`].
    pub version: u32,
    /// The autotune that wrote it (for people: the merge compares the settings, not this).
    pub autotune: String,
    /// What makes the sums.
    pub settings: ShardSettings,
    /// Which share.
    pub shard: ShardIndex,
    /// The share's chunks, ascending.
    pub chunks: Vec<ShardChunk>,
}

/// A check's settings as a shard records them.
pub struct CheckSetup<'a> {
    /// The experiment checked (a problem file's).
    pub experiment: &'a dyn Experiment,
    /// Parameter values.
    pub theta: &'a [f64],
    /// Monte Carlo settings.
    pub mc: &'a McConfig,
    /// Engine path.
    pub engine: Engine,
    /// Judged by NIS alone.
    pub nis_only: bool,
}

impl CheckSetup<'_> {
    /// The settings a shard of this check records; `None` unless the experiment comes from
    /// a problem file (merge reads it again).
    pub fn settings(&self) -> Option<ShardSettings> {
        let e = self.experiment;
        let crate::experiment::Source::File { path, sha256 } = &e.info().source else {
            return None;
        };
        let names = e.params().params.iter().map(|p| p.name.clone());
        Some(ShardSettings {
            problem: e.info().name.clone(),
            file: path.clone(),
            sha256: sha256.clone(),
            params: names
                .zip(self.theta.iter().map(|&v| Number::of(v)))
                .collect(),
            runs: self.mc.runs(),
            steps: self.mc.steps(),
            seed: self.mc.seed(),
            alpha: Number::of(self.mc.alpha()),
            lags: self.mc.lags(),
            gate: value_name(self.mc.gate()),
            engine: value_name(self.engine),
            nis_only: self.nis_only,
            n_x: e.state_names().len(),
            n_z: e.measurement_names().len(),
        })
    }
}

/// A clap value's name (`full`, `auto`).
fn value_name<V: clap::ValueEnum>(v: V) -> String {
    v.to_possible_value()
        .map(|p| p.get_name().to_string())
        .unwrap_or_default()
}

impl ShardSettings {
    pub(super) fn shape(&self) -> SumsShape {
        SumsShape {
            runs: self.runs,
            steps: self.steps,
            lags: self.lags,
            n_x: self.n_x,
            n_z: self.n_z,
        }
    }
}

impl ShardFile {
    /// The file of `share`'s chunk sums `parts` under `settings`.
    pub fn new(settings: ShardSettings, share: Share, parts: &[(usize, Accumulator)]) -> Self {
        let shape = settings.shape();
        let chunks = parts
            .iter()
            .map(|(c, sums)| ShardChunk {
                chunk: *c,
                sums: STANDARD.encode(shape.encode(*c, sums)),
            })
            .collect();
        ShardFile {
            format: FORMAT.to_string(),
            version: VERSION,
            autotune: env!("CARGO_PKG_VERSION").to_string(),
            settings,
            shard: ShardIndex {
                index: share.index(),
                count: share.count(),
            },
            chunks,
        }
    }

    /// The file as JSON text.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a shard serializes")
    }
}

/// A shard file's head: everything but its chunks, read in one streaming pass that skips
/// the chunks' sums without holding them ([`read_head`]).
#[derive(Debug, Clone)]
pub struct ShardHead {
    /// The file.
    pub path: PathBuf,
    /// What makes the sums.
    pub settings: ShardSettings,
    /// Which share.
    pub shard: ShardIndex,
}

/// Why a shard file is refused or shard files do not merge: the file and the reason, one
/// line.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {why}", .file.display())]
pub struct MergeRefusal {
    /// The file at fault (the second of two that differ).
    pub file: PathBuf,
    /// Why.
    pub why: MergeProblem,
}

impl MergeRefusal {
    pub(super) fn new(file: &Path, why: MergeProblem) -> Self {
        MergeRefusal {
            file: file.to_path_buf(),
            why,
        }
    }
}

/// What is wrong with a shard file, or with shard files together ([`MergeRefusal::why`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MergeProblem {
    /// The file cannot be opened as a regular file (the reason in words).
    #[error("{0}")]
    Open(String),
    /// Its size cannot be read.
    #[error("cannot read: {0}")]
    Unreadable(String),
    /// It is larger than a shard file may be, bytes.
    #[error("larger than the limit of {}", crate::userfile::size_text(*.limit))]
    TooLarge {
        /// The limit, bytes.
        limit: u64,
    },
    /// Its head is not a shard file's JSON (the parser's words).
    #[error("not a shard file: {0}")]
    NotJson(String),
    /// Its `format` is not a shard file's.
    #[error("not a shard file (its 'format' is not \"{FORMAT}\")")]
    Format,
    /// Its format version is not the one this autotune reads.
    #[error("shard format version {} (this autotune reads version {VERSION})", .found.map_or("none".to_string(), |v| v.to_string()))]
    Version {
        /// The version it gives, if any.
        found: Option<u32>,
    },
    /// It has no `settings` or no `shard`.
    #[error("not a shard file: it has no 'settings' or no 'shard'")]
    Incomplete,
    /// No shard files were given.
    #[error("no shard files")]
    NoFiles,
    /// A setting differs from the first file's.
    #[error("its {field} differs from {}'s: shards of different problems or settings do not merge", .first.display())]
    Differs {
        /// The setting, as the file names it.
        field: &'static str,
        /// The first file.
        first: PathBuf,
    },
    /// It is a share of another count than the first file's.
    #[error("shard {index}/{count} cannot merge with {}'s shards of {first_count}", .first.display())]
    OtherCount {
        /// Its share index.
        index: usize,
        /// Its share count.
        count: usize,
        /// The first file.
        first: PathBuf,
        /// The first file's share count.
        first_count: usize,
    },
    /// Its share index is not below the count.
    #[error("shard {index}/{count} is not a shard of {count}")]
    OutOfRange {
        /// Its share index.
        index: usize,
        /// The share count.
        count: usize,
    },
    /// Another file is the same share.
    #[error("shard {index}/{count} is also {}", .other.display())]
    Duplicate {
        /// The share index.
        index: usize,
        /// The share count.
        count: usize,
        /// The other file.
        other: PathBuf,
    },
    /// No file is this share.
    #[error("shard {index}/{count} is missing: give every shard's file")]
    Missing {
        /// The missing share's index.
        index: usize,
        /// The share count.
        count: usize,
    },
    /// Its share cannot be formed (the reason in words).
    #[error("{0}")]
    Share(SettingError),
    /// Its reader thread could not start.
    #[error("cannot start its reader: {0}")]
    Reader(String),
    /// A chunk comes out of its place.
    #[error("chunk {got} comes where chunk {want} belongs")]
    OutOfOrder {
        /// The chunk found.
        got: usize,
        /// The chunk that belongs there.
        want: usize,
    },
    /// The file ends before one of its share's chunks.
    #[error("chunk {0} is missing: the file ends before it")]
    Truncated(usize),
    /// A chunk beyond the check's chunks.
    #[error("chunk {chunk} is not one of the check's {chunks} chunks")]
    Extra {
        /// The chunk found.
        chunk: usize,
        /// The check's chunk count.
        chunks: usize,
    },
    /// Its reader stopped without a word.
    #[error("its reader stopped")]
    Stopped,
    /// The check has no chunks.
    #[error("no chunks to merge")]
    NoChunks,
    /// Its chunks do not read (the parser's or the decoder's words).
    #[error("{0}")]
    Chunks(String),
}

/// Why a shard file's settings do not describe a check of the problem they name
/// ([`ShardSettings::setup`]).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SetupRefusal {
    /// The parameters are not the problem's (which are these, in order).
    #[error("its parameters are not the problem's ({})", .problem.join(", "))]
    Parameters {
        /// The problem's parameter names.
        problem: Vec<String>,
    },
    /// A parameter's value is not a finite number.
    #[error("its settings' params.{0} is not a finite number")]
    NotFinite(String),
    /// The sums' dimension is not the problem's.
    #[error("its settings' {field} is {declared}, but the problem's sums have {actual}")]
    Dimension {
        /// `n_x` or `n_z`.
        field: &'static str,
        /// What the settings say.
        declared: usize,
        /// What the problem has.
        actual: usize,
    },
    /// A setting that does not read (`alpha`, `gate`, `engine`).
    #[error("its settings' {0} is not valid")]
    Invalid(&'static str),
    /// The Monte Carlo settings are refused as `check` refuses them.
    #[error("its settings: {0}")]
    Settings(SettingError),
}

/// A check as its shards' settings describe it, checked against the problem it names (its
/// parameters, and the components of its sums) before anything is sized by them.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The parameter values, every one finite.
    pub theta: Vec<f64>,
    /// The Monte Carlo settings (validated as `check` validates them).
    pub mc: McConfig,
    /// The engine path asked for.
    pub engine: Engine,
}

impl ShardSettings {
    /// The check these settings describe, on `experiment` (the problem they name, read
    /// again): the parameters must be its parameters and finite, the sums' components its
    /// components, the Monte Carlo settings valid. `Err` says why.
    pub fn setup(&self, experiment: &dyn Experiment) -> Result<Setup, SetupRefusal> {
        let s = self;
        let names = experiment.params().names();
        if !names
            .iter()
            .copied()
            .eq(s.params.iter().map(|(n, _)| n.as_str()))
        {
            return Err(SetupRefusal::Parameters {
                problem: names.iter().map(|n| n.to_string()).collect(),
            });
        }
        let theta = s
            .params
            .iter()
            .map(|(name, v)| {
                v.get()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| SetupRefusal::NotFinite(name.clone()))
            })
            .collect::<Result<Vec<f64>, SetupRefusal>>()?;
        for (field, declared, actual) in [
            ("n_x", s.n_x, experiment.state_names().len()),
            ("n_z", s.n_z, experiment.measurement_names().len()),
        ] {
            if declared != actual {
                return Err(SetupRefusal::Dimension {
                    field,
                    declared,
                    actual,
                });
            }
        }
        let alpha = s.alpha.get().ok_or(SetupRefusal::Invalid("alpha"))?;
        let gate = <GateMode as clap::ValueEnum>::from_str(&s.gate, false)
            .map_err(|_| SetupRefusal::Invalid("gate"))?;
        let engine = <Engine as clap::ValueEnum>::from_str(&s.engine, false)
            .map_err(|_| SetupRefusal::Invalid("engine"))?;
        let mc = McConfig::new(s.runs, s.steps)
            .and_then(|mc| mc.with_alpha(alpha))
            .and_then(|mc| mc.with_lags(s.lags))
            .map_err(SetupRefusal::Settings)?
            .with_seed(s.seed)
            .with_gate(gate);
        Ok(Setup { theta, mc, engine })
    }
}

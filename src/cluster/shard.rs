//! Shard files: one share of a check's chunk sums, written by `autotune check --shard i/n
//! --sums-out FILE` and merged by `autotune merge` (format: docs/src/cluster.md).
//!
//! A shard file is one JSON document: the format and its version, the settings that make
//! its sums (the problem's name, path and SHA-256, the parameter values and the Monte Carlo
//! settings, each number with its IEEE bits), which share it is, and each of its chunks'
//! sums in autotune's sums format (base64, the format a worker's sums answer uses). Shards
//! merge only when every setting is the same, every share of the count is there once and
//! every chunk once: the merged sums are then the one-process sums, bit for bit.

use std::path::{Path, PathBuf};

use base64::Engine as _;
use base64::engine::general_purpose::STANDARD;
use serde::{Deserialize, Serialize};

use super::SumsShape;
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
    fn of(x: f64) -> Number {
        Number {
            value: serde_json::Number::from_f64(x).unwrap_or_else(|| 0.into()),
            bits: format!("{:016x}", x.to_bits()),
        }
    }

    fn get(&self) -> Option<f64> {
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
    fn shape(&self) -> SumsShape {
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

    /// A shard file's text, checked for its format and version; `Err` says why in words.
    pub fn parse(text: &str) -> Result<ShardFile, String> {
        #[derive(Deserialize)]
        struct Head {
            format: Option<String>,
            version: Option<u32>,
        }
        let head: Head = serde_json::from_str(text).map_err(|e| format!("not JSON: {e}"))?;
        if head.format.as_deref() != Some(FORMAT) {
            return Err(format!(
                "not a shard file (its 'format' is not \"{FORMAT}\")"
            ));
        }
        if head.version != Some(VERSION) {
            return Err(format!(
                "shard format version {} (this autotune reads version {VERSION})",
                head.version.map_or("none".to_string(), |v| v.to_string())
            ));
        }
        serde_json::from_str(text).map_err(|e| e.to_string())
    }
}

/// Why shard files do not merge: the file and the reason, one line.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {why}", .file.display())]
pub struct MergeRefusal {
    /// The file at fault (the second of two that differ).
    pub file: PathBuf,
    /// Why.
    pub why: String,
}

/// The settings and merged sums of a check's shards, as they came from `files` (path and
/// parsed contents): the one-process sums, bit for bit.
pub struct Merged {
    /// What made the sums.
    pub settings: ShardSettings,
    /// The parameter values.
    pub theta: Vec<f64>,
    /// The Monte Carlo settings.
    pub mc: McConfig,
    /// The engine path asked for.
    pub engine: Engine,
    /// The sums of every chunk, merged in chunk order.
    pub sums: Accumulator,
}

/// Merge shard files: every setting the same as the first file's, each share of the count
/// once, each chunk once.
pub fn merge(files: &[(PathBuf, ShardFile)]) -> Result<Merged, MergeRefusal> {
    let refuse = |file: &Path, why: String| MergeRefusal {
        file: file.to_path_buf(),
        why,
    };
    let Some((first_path, first)) = files.first() else {
        return Err(refuse(Path::new("autotune merge"), "no shard files".into()));
    };
    let s = &first.settings;
    let count = first.shard.count;
    let mut seen = vec![None::<&Path>; count];
    for (path, f) in files {
        if let Some(field) = first_difference(s, &f.settings) {
            return Err(refuse(
                path,
                format!(
                    "its {field} differs from {}'s: shards of different problems or settings do not merge",
                    first_path.display()
                ),
            ));
        }
        if f.shard.count != count {
            return Err(refuse(
                path,
                format!(
                    "shard {}/{} cannot merge with {}'s shards of {count}",
                    f.shard.index,
                    f.shard.count,
                    first_path.display()
                ),
            ));
        }
        let slot = seen.get_mut(f.shard.index).ok_or_else(|| {
            refuse(
                path,
                format!("shard {}/{count} is not a shard of {count}", f.shard.index),
            )
        })?;
        if let Some(other) = slot.replace(path) {
            return Err(refuse(
                path,
                format!(
                    "shard {}/{count} is also {}",
                    f.shard.index,
                    other.display()
                ),
            ));
        }
    }
    if let Some(missing) = seen.iter().position(Option::is_none) {
        return Err(refuse(
            first_path,
            format!("shard {missing}/{count} is missing: give every shard's file"),
        ));
    }
    let (theta, mc, engine) = setup(s).map_err(|why| refuse(first_path, why))?;
    let shape = s.shape();
    let mut parts = Vec::new();
    for (path, f) in files {
        let share = Share::new(f.shard.index, count).map_err(|e| refuse(path, e.to_string()))?;
        for c in &f.chunks {
            if !share.owns_chunk(c.chunk) || c.chunk >= shape.chunks() {
                return Err(refuse(
                    path,
                    format!("chunk {} is not shard {}/{count}'s", c.chunk, f.shard.index),
                ));
            }
            let bytes = STANDARD
                .decode(&c.sums)
                .map_err(|e| refuse(path, format!("chunk {}: not base64: {e}", c.chunk)))?;
            let sums = shape
                .decode(c.chunk, &bytes)
                .map_err(|e| refuse(path, format!("chunk {}: {e}", c.chunk)))?;
            parts.push((c.chunk, sums));
        }
    }
    let sums = Share::merge(s.runs, shape.empty(), parts)
        .map_err(|e| refuse(first_path, e.to_string()))?;
    Ok(Merged {
        settings: s.clone(),
        theta,
        mc,
        engine,
        sums,
    })
}

/// The first setting in which `b` differs from `a`, by the name the file gives it.
fn first_difference(a: &ShardSettings, b: &ShardSettings) -> Option<&'static str> {
    let fields: [(&'static str, bool); 15] = [
        ("problem", a.problem == b.problem),
        ("file", a.file == b.file),
        ("sha256 (the problem file's digest)", a.sha256 == b.sha256),
        ("params", a.params == b.params),
        ("runs", a.runs == b.runs),
        ("steps", a.steps == b.steps),
        ("seed", a.seed == b.seed),
        ("alpha", a.alpha == b.alpha),
        ("lags", a.lags == b.lags),
        ("gate", a.gate == b.gate),
        ("engine", a.engine == b.engine),
        ("nis_only", a.nis_only == b.nis_only),
        ("n_x", a.n_x == b.n_x),
        ("n_z", a.n_z == b.n_z),
        ("settings", a == b),
    ];
    fields.iter().find(|(_, same)| !same).map(|(f, _)| *f)
}

/// The parameter values, Monte Carlo settings and engine a shard's settings describe.
fn setup(s: &ShardSettings) -> Result<(Vec<f64>, McConfig, Engine), String> {
    let bad = |field: &str| format!("its settings' {field} is not valid");
    let theta = s
        .params
        .iter()
        .map(|(name, v)| v.get().ok_or_else(|| bad(&format!("params.{name}"))))
        .collect::<Result<Vec<f64>, String>>()?;
    let setting = |e: SettingError| format!("its settings: {e}");
    let alpha = s.alpha.get().ok_or_else(|| bad("alpha"))?;
    let gate = <GateMode as clap::ValueEnum>::from_str(&s.gate, false).map_err(|_| bad("gate"))?;
    let engine =
        <Engine as clap::ValueEnum>::from_str(&s.engine, false).map_err(|_| bad("engine"))?;
    let mc = McConfig::new(s.runs, s.steps)
        .and_then(|mc| mc.with_alpha(alpha))
        .and_then(|mc| mc.with_lags(s.lags))
        .map_err(setting)?
        .with_seed(s.seed)
        .with_gate(gate);
    Ok((theta, mc, engine))
}

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
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{}: {why}", .file.display())]
pub struct MergeRefusal {
    /// The file at fault (the second of two that differ).
    pub file: PathBuf,
    /// Why.
    pub why: String,
}

impl MergeRefusal {
    fn new(file: &Path, why: impl Into<String>) -> Self {
        MergeRefusal {
            file: file.to_path_buf(),
            why: why.into(),
        }
    }
}

/// Open a shard file to read: a regular file of at most [`MAX_FILE`] bytes (checked on the
/// opened descriptor), noted as an input of this process.
fn open(path: &Path) -> Result<(std::fs::File, u64), MergeRefusal> {
    let file = crate::userfile::open(path).map_err(|e| MergeRefusal::new(path, e.message))?;
    crate::input::note_input(path);
    let len = file
        .metadata()
        .map_err(|e| MergeRefusal::new(path, format!("cannot read: {e}")))?
        .len();
    if len > MAX_FILE {
        return Err(MergeRefusal::new(
            path,
            format!(
                "larger than the limit of {}",
                crate::userfile::size_text(MAX_FILE)
            ),
        ));
    }
    Ok((file, len))
}

/// A shard file's head, its format and version checked. The file is streamed: the chunks'
/// sums are skipped without being held, so memory stays small whatever the file holds.
pub fn read_head(path: &Path) -> Result<ShardHead, MergeRefusal> {
    #[derive(Deserialize)]
    struct Head {
        format: Option<String>,
        version: Option<u32>,
        settings: Option<ShardSettings>,
        shard: Option<ShardIndex>,
    }
    let (file, _) = open(path)?;
    let reader = std::io::BufReader::with_capacity(1 << 16, file);
    let head: Head = serde_json::from_reader(reader)
        .map_err(|e| MergeRefusal::new(path, format!("not a shard file: {e}")))?;
    if head.format.as_deref() != Some(FORMAT) {
        return Err(MergeRefusal::new(
            path,
            format!("not a shard file (its 'format' is not \"{FORMAT}\")"),
        ));
    }
    if head.version != Some(VERSION) {
        return Err(MergeRefusal::new(
            path,
            format!(
                "shard format version {} (this autotune reads version {VERSION})",
                head.version.map_or("none".to_string(), |v| v.to_string())
            ),
        ));
    }
    let (Some(settings), Some(shard)) = (head.settings, head.shard) else {
        return Err(MergeRefusal::new(
            path,
            "not a shard file: it has no 'settings' or no 'shard'",
        ));
    };
    Ok(ShardHead {
        path: path.to_path_buf(),
        settings,
        shard,
    })
}

/// Check that `heads` are the shards of one check, every share of the count once, and
/// return them ordered by share. The count is bounded by the files given before anything
/// is sized by it.
pub fn plan(heads: &[ShardHead]) -> Result<Vec<&ShardHead>, MergeRefusal> {
    let Some(first) = heads.first() else {
        return Err(MergeRefusal::new(
            Path::new("autotune merge"),
            "no shard files",
        ));
    };
    let s = &first.settings;
    let count = first.shard.count;
    for h in heads {
        if let Some(field) = first_difference(s, &h.settings) {
            return Err(MergeRefusal::new(
                &h.path,
                format!(
                    "its {field} differs from {}'s: shards of different problems or settings do not merge",
                    first.path.display()
                ),
            ));
        }
        if h.shard.count != count {
            return Err(MergeRefusal::new(
                &h.path,
                format!(
                    "shard {}/{} cannot merge with {}'s shards of {count}",
                    h.shard.index,
                    h.shard.count,
                    first.path.display()
                ),
            ));
        }
        if h.shard.index >= count {
            return Err(MergeRefusal::new(
                &h.path,
                format!("shard {}/{count} is not a shard of {count}", h.shard.index),
            ));
        }
    }
    // Each share once: the count cannot exceed the files given, or some share is missing.
    let mut ordered: Vec<&ShardHead> = heads.iter().collect();
    ordered.sort_by_key(|h| h.shard.index);
    for w in ordered.windows(2) {
        if w[0].shard.index == w[1].shard.index {
            return Err(MergeRefusal::new(
                &w[1].path,
                format!(
                    "shard {}/{count} is also {}",
                    w[1].shard.index,
                    w[0].path.display()
                ),
            ));
        }
    }
    if let Some(missing) = (0..count).find(|&i| ordered.get(i).is_none_or(|h| h.shard.index != i)) {
        return Err(MergeRefusal::new(
            &first.path,
            format!("shard {missing}/{count} is missing: give every shard's file"),
        ));
    }
    Ok(ordered)
}

/// What one shard file's reader hands on: chunk `c`'s sums, or the end of the file with
/// the number of chunks it held, or why it stopped.
enum Read {
    Chunk(usize, Box<Accumulator>),
    End,
    Refused(MergeRefusal),
}

/// The merged sums of the shards `ordered` (one per share, in share order, as [`plan`]
/// returns them), whose settings give `shape`: chunk c from share c mod n, merged in chunk
/// order into fresh sums, which is what one process computes, bit for bit.
///
/// Each file is streamed by a reader thread of its own that decodes one chunk at a time
/// and hands it on through a channel of one: memory stays at about one chunk per file (a
/// wave), whatever the files hold. A chunk's text is read only up to the longest its shape
/// can encode to, and decoded only when its shape's bytes are there, so nothing is sized by
/// a number the file declares but does not back. The merged sums are allocated once the
/// first chunk has shown that its shape is real.
pub fn merge_stream(
    ordered: &[&ShardHead],
    shape_of: &ShardSettings,
) -> Result<Accumulator, MergeRefusal> {
    let shape = shape_of.shape();
    let count = ordered.len();
    std::thread::scope(|scope| {
        let mut readers = Vec::with_capacity(count);
        for h in ordered {
            let (tx, rx) = std::sync::mpsc::sync_channel::<Read>(1);
            let share = Share::new(h.shard.index, count)
                .map_err(|e| MergeRefusal::new(&h.path, e.to_string()))?;
            let shape = &shape;
            std::thread::Builder::new()
                .stack_size(1 << 20)
                .spawn_scoped(scope, move || stream_chunks(h, share, shape, &tx))
                .map_err(|e| MergeRefusal::new(&h.path, format!("cannot start its reader: {e}")))?;
            readers.push((h, rx));
        }
        let mut merged: Option<Accumulator> = None;
        let chunks = shape.chunks();
        for c in 0..chunks {
            let (h, rx) = &readers[c % count];
            match rx.recv() {
                Ok(Read::Chunk(got, sums)) if got == c => {
                    merged.get_or_insert_with(|| shape.empty()).merge(&sums);
                }
                Ok(Read::Chunk(got, _)) => {
                    return Err(MergeRefusal::new(
                        &h.path,
                        format!("chunk {got} comes where chunk {c} belongs"),
                    ));
                }
                Ok(Read::End) | Err(_) => {
                    return Err(MergeRefusal::new(
                        &h.path,
                        format!("chunk {c} is missing: the file ends before it"),
                    ));
                }
                Ok(Read::Refused(r)) => return Err(r),
            }
        }
        for (h, rx) in &readers {
            match rx.recv() {
                Ok(Read::End) => {}
                Ok(Read::Refused(r)) => return Err(r),
                Ok(Read::Chunk(c, _)) => {
                    return Err(MergeRefusal::new(
                        &h.path,
                        format!("chunk {c} is not one of the check's {chunks} chunks"),
                    ));
                }
                Err(_) => {
                    return Err(MergeRefusal::new(&h.path, "its reader stopped"));
                }
            }
        }
        merged.ok_or_else(|| MergeRefusal::new(&ordered[0].path, "no chunks to merge"))
    })
}

/// A reader that counts what is read through it against a budget the caller resets: the
/// longest text one chunk may take.
struct Budget<R> {
    inner: R,
    left: std::rc::Rc<std::cell::Cell<u64>>,
}

impl<R: std::io::Read> std::io::Read for Budget<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let left = self.left.get();
        if left == 0 {
            return Err(std::io::Error::other(
                "a chunk's sums are longer than its shape allows",
            ));
        }
        let n = buf.len().min(usize::try_from(left).unwrap_or(usize::MAX));
        let got = self.inner.read(&mut buf[..n])?;
        self.left.set(left - got as u64);
        Ok(got)
    }
}

/// The longest base64 text chunk `c` of `shape` can take (every divergence kept, with its
/// longest reason), with room for the JSON around it; `None` where it overflows.
fn longest_chunk_text(shape: &SumsShape, c: usize) -> Option<u64> {
    let least = crate::records::min_sums_len(&shape.chunk(c))?;
    // Each of at most 64 kept divergences: run, step, cause, reason length, reason.
    let most = least.checked_add(64 * (8 + 8 + 1 + 8 + 1000))?;
    (most.checked_add(2)? / 3)
        .checked_mul(4)?
        .checked_add(4096)
        .map(|x| x as u64)
}

/// Stream `h`'s chunks into `tx`: each checked to be the share's next chunk of the check,
/// its text bounded by its shape's longest, decoded against its shape.
fn stream_chunks(
    h: &ShardHead,
    share: Share,
    shape: &SumsShape,
    tx: &std::sync::mpsc::SyncSender<Read>,
) {
    use serde::de::{self, DeserializeSeed, MapAccess, SeqAccess, Visitor};
    let refuse = |why: String| {
        let _ = tx.send(Read::Refused(MergeRefusal::new(&h.path, why)));
    };
    let file = match open(&h.path) {
        Ok((f, _)) => f,
        Err(r) => return drop(tx.send(Read::Refused(r))),
    };
    // The head was read before: the budget covers it until the chunks start.
    let left = std::rc::Rc::new(std::cell::Cell::new(MAX_FILE));
    let reader = Budget {
        inner: std::io::BufReader::with_capacity(1 << 16, file),
        left: left.clone(),
    };

    struct Ctx<'a> {
        h: &'a ShardHead,
        share: Share,
        shape: &'a SumsShape,
        tx: &'a std::sync::mpsc::SyncSender<Read>,
        left: std::rc::Rc<std::cell::Cell<u64>>,
    }
    struct File<'a>(&'a Ctx<'a>);
    struct Chunks<'a>(&'a Ctx<'a>);
    #[derive(Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Chunk {
        chunk: usize,
        sums: String,
    }
    impl<'de> Visitor<'de> for File<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a shard file")
        }
        fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
            let (mut settings, mut shard) = (None::<ShardSettings>, None::<ShardIndex>);
            while let Some(key) = map.next_key::<String>()? {
                match key.as_str() {
                    "chunks" => map.next_value_seed(Chunks(self.0))?,
                    "settings" => settings = Some(map.next_value()?),
                    "shard" => shard = Some(map.next_value()?),
                    _ => {
                        map.next_value::<de::IgnoredAny>()?;
                    }
                }
            }
            // The file must still be the one whose head was read.
            if settings.as_ref() != Some(&self.0.h.settings) || shard != Some(self.0.h.shard) {
                return Err(de::Error::custom("the file changed while it was merged"));
            }
            Ok(())
        }
    }
    impl<'de> DeserializeSeed<'de> for File<'_> {
        type Value = ();
        fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_map(self)
        }
    }
    impl<'de> DeserializeSeed<'de> for Chunks<'_> {
        type Value = ();
        fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<(), D::Error> {
            d.deserialize_seq(self)
        }
    }
    impl<'de> Visitor<'de> for Chunks<'_> {
        type Value = ();
        fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
            f.write_str("a list of chunks")
        }
        fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
            let cx = self.0;
            let count = cx.share.count();
            // The share's chunks, ascending: index, index + n, …
            let mut next = cx.share.index();
            loop {
                let budget =
                    longest_chunk_text(cx.shape, next.min(cx.shape.chunks().saturating_sub(1)))
                        .unwrap_or(0);
                cx.left.set(budget);
                let Some(chunk) = seq.next_element::<Chunk>()? else {
                    break;
                };
                if chunk.chunk != next {
                    return Err(de::Error::custom(
                        if cx.share.owns_chunk(chunk.chunk) && chunk.chunk < cx.shape.chunks() {
                            format!(
                                "chunk {} comes where chunk {next} belongs (chunks ascend, each once)",
                                chunk.chunk
                            )
                        } else {
                            format!(
                                "chunk {} is not shard {}/{count}'s",
                                chunk.chunk,
                                cx.share.index()
                            )
                        },
                    ));
                }
                if chunk.chunk >= cx.shape.chunks() {
                    return Err(de::Error::custom(format!(
                        "chunk {} is not one of the check's {} chunks",
                        chunk.chunk,
                        cx.shape.chunks()
                    )));
                }
                let bytes = STANDARD.decode(&chunk.sums).map_err(|e| {
                    de::Error::custom(format!("chunk {}: not base64: {e}", chunk.chunk))
                })?;
                drop(chunk.sums);
                let sums = cx
                    .shape
                    .decode(next, &bytes)
                    .map_err(|e| de::Error::custom(format!("chunk {next}: {e}")))?;
                if cx.tx.send(Read::Chunk(next, Box::new(sums))).is_err() {
                    return Err(de::Error::custom("stopped"));
                }
                next += count;
            }
            cx.left.set(MAX_FILE);
            Ok(())
        }
    }

    let cx = Ctx {
        h,
        share,
        shape,
        tx,
        left,
    };
    let mut de = serde_json::Deserializer::from_reader(reader);
    match File(&cx).deserialize(&mut de).and_then(|()| de.end()) {
        Ok(()) => drop(tx.send(Read::End)),
        Err(e) => refuse(e.to_string()),
    }
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
    /// components, the Monte Carlo settings valid. `Err` says why in words.
    pub fn setup(&self, experiment: &dyn Experiment) -> Result<Setup, String> {
        let s = self;
        let bad = |field: &str| format!("its settings' {field} is not valid");
        let names = experiment.params().names();
        if !names
            .iter()
            .copied()
            .eq(s.params.iter().map(|(n, _)| n.as_str()))
        {
            return Err(format!(
                "its parameters are not the problem's ({})",
                names.join(", ")
            ));
        }
        let theta = s
            .params
            .iter()
            .map(|(name, v)| {
                v.get()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("its settings' params.{name} is not a finite number"))
            })
            .collect::<Result<Vec<f64>, String>>()?;
        for (field, declared, actual) in [
            ("n_x", s.n_x, experiment.state_names().len()),
            ("n_z", s.n_z, experiment.measurement_names().len()),
        ] {
            if declared != actual {
                return Err(format!(
                    "its settings' {field} is {declared}, but the problem's sums have {actual}"
                ));
            }
        }
        let setting = |e: SettingError| format!("its settings: {e}");
        let alpha = s.alpha.get().ok_or_else(|| bad("alpha"))?;
        let gate =
            <GateMode as clap::ValueEnum>::from_str(&s.gate, false).map_err(|_| bad("gate"))?;
        let engine =
            <Engine as clap::ValueEnum>::from_str(&s.engine, false).map_err(|_| bad("engine"))?;
        let mc = McConfig::new(s.runs, s.steps)
            .and_then(|mc| mc.with_alpha(alpha))
            .and_then(|mc| mc.with_lags(s.lags))
            .map_err(setting)?
            .with_seed(s.seed)
            .with_gate(gate);
        Ok(Setup { theta, mc, engine })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::montecarlo::CHUNK;

    /// A check of 130 runs (three chunks: 64, 64 and 2 runs) of 3 steps, 2 states, 1
    /// measurement component and 1 lag.
    fn settings() -> ShardSettings {
        ShardSettings {
            problem: "p".into(),
            file: PathBuf::from("p.toml"),
            sha256: "00".into(),
            params: vec![("q".into(), Number::of(0.5))],
            runs: 2 * CHUNK + 2,
            steps: 3,
            seed: 7,
            alpha: Number::of(0.05),
            lags: 1,
            gate: "full".into(),
            engine: "auto".into(),
            nis_only: false,
            n_x: 2,
            n_z: 1,
        }
    }

    fn head(name: &str, index: usize, count: usize, settings: &ShardSettings) -> ShardHead {
        ShardHead {
            path: PathBuf::from(name),
            settings: settings.clone(),
            shard: ShardIndex { index, count },
        }
    }

    fn refused(heads: &[ShardHead]) -> String {
        plan(heads).unwrap_err().to_string()
    }

    #[test]
    fn plan_orders_the_shares_and_names_the_file_at_fault() {
        let s = settings();
        let heads = [
            head("c", 2, 3, &s),
            head("a", 0, 3, &s),
            head("b", 1, 3, &s),
        ];
        let order: Vec<_> = plan(&heads).unwrap().iter().map(|h| &h.path).collect();
        assert_eq!(order, [Path::new("a"), Path::new("b"), Path::new("c")]);

        assert_eq!(refused(&[]), "autotune merge: no shard files");
        let mut other = s.clone();
        other.steps = 4;
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 1, 2, &other)]),
            "b: its steps differs from a's: shards of different problems or settings do not merge"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 1, 3, &s)]),
            "b: shard 1/3 cannot merge with a's shards of 2"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 2, 2, &s)]),
            "b: shard 2/2 is not a shard of 2"
        );
        assert_eq!(
            refused(&[head("a", 0, 2, &s), head("b", 0, 2, &s)]),
            "b: shard 0/2 is also a"
        );
        assert_eq!(
            refused(&[head("a", 0, 3, &s), head("b", 2, 3, &s)]),
            "a: shard 1/3 is missing: give every shard's file"
        );
    }

    #[test]
    fn every_setting_that_differs_is_named() {
        type Change = fn(&mut ShardSettings);
        let changes: [(&str, Change); 14] = [
            ("problem", |s| s.problem.push('x')),
            ("file", |s| s.file.push("x")),
            ("sha256 (the problem file's digest)", |s| s.sha256.push('1')),
            ("params", |s| s.params[0].1 = Number::of(0.25)),
            ("runs", |s| s.runs += 1),
            ("steps", |s| s.steps += 1),
            ("seed", |s| s.seed += 1),
            ("alpha", |s| s.alpha = Number::of(0.01)),
            ("lags", |s| s.lags += 1),
            ("gate", |s| s.gate = "mean".into()),
            ("engine", |s| s.engine = "generic".into()),
            ("nis_only", |s| s.nis_only = true),
            ("n_x", |s| s.n_x += 1),
            ("n_z", |s| s.n_z += 1),
        ];
        let s = settings();
        assert_eq!(first_difference(&s, &s.clone()), None);
        for (field, change) in changes {
            let mut o = s.clone();
            change(&mut o);
            assert_eq!(first_difference(&s, &o), Some(field));
        }
    }

    #[test]
    fn a_number_keeps_its_bits() {
        for x in [0.1, -0.0, f64::MIN_POSITIVE / 3.0, 1e308, f64::NAN] {
            assert_eq!(Number::of(x).get().map(f64::to_bits), Some(x.to_bits()));
        }
        let bad = Number {
            value: 1.into(),
            bits: "not hex".into(),
        };
        assert_eq!(bad.get(), None);
    }

    /// Chunk `c`'s sums with values that differ by chunk, step and component.
    fn chunk_sums(s: &ShardSettings, c: usize) -> Accumulator {
        let mut a = s.shape().empty();
        a.runs = (s.runs - c * CHUNK).min(CHUNK);
        for k in 0..s.steps {
            a.nees_sum[k] = (c * 7 + k) as f64 / 3.0;
            a.nis_sum[k] = 1.0 / (1.0 + (c * 5 + k) as f64);
        }
        a.state_comp_total[1] = c as f64 + 0.1;
        a
    }

    #[test]
    fn shard_files_merge_into_the_one_process_sums_bit_for_bit() {
        let s = settings();
        let chunks = s.runs.div_ceil(CHUNK);
        let dir = tempfile::tempdir().unwrap();
        let mut heads = Vec::new();
        for i in 0..2 {
            let share = Share::new(i, 2).unwrap();
            let parts: Vec<(usize, Accumulator)> = share
                .chunks(chunks)
                .map(|c| (c, chunk_sums(&s, c)))
                .collect();
            let path = dir.path().join(format!("shard{i}.json"));
            std::fs::write(&path, ShardFile::new(s.clone(), share, &parts).to_json()).unwrap();
            heads.push(read_head(&path).unwrap());
        }
        heads.reverse();
        let merged = merge_stream(&plan(&heads).unwrap(), &s).unwrap();
        let parts = (0..chunks).map(|c| (c, chunk_sums(&s, c))).collect();
        let one = Share::merge(s.runs, s.shape().empty(), parts).unwrap();
        // Debug prints each float's shortest exact form: equal text, equal bits.
        assert_eq!(format!("{merged:?}"), format!("{one:?}"));
        assert_eq!(merged.runs, s.runs);
    }

    #[test]
    fn a_chunk_decodes_only_into_its_own_shape() {
        let s = settings().shape();
        let sums = chunk_sums(&settings(), 2);
        let bytes = s.encode(2, &sums);
        let back = s.decode(2, &bytes).unwrap();
        assert_eq!(format!("{back:?}"), format!("{sums:?}"));
        // Chunk 0 holds 64 runs, chunk 2 only 2: its bytes are not chunk 0's.
        assert!(s.decode(0, &bytes).is_err());
        assert!(s.decode(2, &bytes[..bytes.len() - 1]).is_err());
    }
}

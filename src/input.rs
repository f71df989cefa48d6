//! Reading inputs: TOML files with errors that name the file, the field and the line, and
//! values checked where they are set, with errors that name the setting.
//!
//! These two error types are the bottom of every input path. A problem file's loader turns
//! a [`SettingError`] into a [`FileError`] at `montecarlo.runs` or `tune.max_evals`; the
//! command line turns it into an error naming the flag (`--runs`).

use std::ffi::OsStr;
use std::marker::PhantomData;

use clap::ValueEnum;
use clap::builder::{PossibleValue, TypedValueParser};
use clap::error::ErrorKind;
use std::fmt;
use std::path::{Path, PathBuf};

/// A bad input file: which file, which field, what is wrong (one line).
#[derive(Debug, Clone, PartialEq)]
pub struct FileError {
    /// The file.
    pub file: PathBuf,
    /// Dotted path of the field, e.g. `truth.Q[1].indices` (empty for the whole file).
    pub field: String,
    /// Line in the file, where known.
    pub line: Option<usize>,
    /// What is wrong, on one line.
    pub message: String,
}

impl FileError {
    /// An error at `field` of `file`, line unknown.
    pub fn new(file: &Path, field: impl Into<String>, message: impl Into<String>) -> Self {
        FileError {
            file: file.to_path_buf(),
            field: field.into(),
            line: None,
            message: message.into(),
        }
    }

    /// A setting's error as an error at `prefix` + the setting's name in `file` (e.g.
    /// `tune.` + `max_evals`).
    pub fn from_setting(file: &Path, prefix: &str, e: SettingError) -> Self {
        FileError::new(file, format!("{prefix}{}", e.setting), e.message)
    }
}

impl fmt::Display for FileError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(l) = self.line {
            write!(f, ":{l}")?;
        }
        if !self.field.is_empty() {
            write!(f, ": {}", self.field)?;
        }
        write!(f, ": {}", self.message)
    }
}

impl std::error::Error for FileError {}

/// A value a setter refused: the setting's name (as in a problem file's table, e.g.
/// `runs`, `max_evals`, `weights.shape`) and why.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{setting}: {message}")]
pub struct SettingError {
    /// The setting.
    pub setting: String,
    /// What is wrong with the value, on one line.
    pub message: String,
}

impl SettingError {
    /// An error for `setting`.
    pub fn new(setting: impl Into<String>, message: impl Into<String>) -> Self {
        SettingError {
            setting: setting.into(),
            message: message.into(),
        }
    }

    /// The same error for a setting inside `table` (`value` in `params.q` becomes
    /// `params.q.value`; an error of the whole item becomes `params.q`).
    pub fn within(self, table: &str) -> Self {
        let setting = if self.setting.is_empty() {
            table.to_string()
        } else {
            format!("{table}.{}", self.setting)
        };
        SettingError { setting, ..self }
    }
}

/// `v` as a count of at least `min`, or an error for `setting` that shows `v` as given (so a
/// negative TOML integer is reported as written).
pub fn at_least<T: TryInto<usize> + std::fmt::Display + Copy>(
    setting: &str,
    v: T,
    min: usize,
) -> Result<usize, SettingError> {
    v.try_into()
        .ok()
        .filter(|&n| n >= min)
        .ok_or_else(|| SettingError::new(setting, format!("{v} must be ≥ {min}")))
}

/// `n` if it is at most `max`, or an error for `setting`.
pub fn at_most(setting: &str, n: usize, max: usize) -> Result<usize, SettingError> {
    if n > max {
        return Err(SettingError::new(setting, format!("{n} must be ≤ {max}")));
    }
    Ok(n)
}

/// Deserialize TOML into `T`, turning syntax and schema errors into a [`FileError`] with the
/// field path and line.
pub fn parse_toml<T: serde::de::DeserializeOwned>(text: &str, path: &Path) -> Result<T, FileError> {
    let line_of = |span: Option<std::ops::Range<usize>>| {
        span.map(|s| text[..s.start.min(text.len())].matches('\n').count() + 1)
    };
    let one_line = |m: &str| m.trim().replace('\n', "; ");
    let de = toml::de::Deserializer::parse(text).map_err(|e| FileError {
        file: path.to_path_buf(),
        field: String::new(),
        line: line_of(e.span()),
        message: format!("malformed TOML: {}", one_line(e.message())),
    })?;
    serde_path_to_error::deserialize(de).map_err(|e| {
        // A table read in file order (`toml::Spanned` entries) puts the wrapper's private
        // key into the path; the user's field is the path without it.
        let field = e
            .path()
            .to_string()
            .replace(".$__serde_spanned_private_value", "");
        let inner = e.into_inner();
        FileError {
            file: path.to_path_buf(),
            field: if field == "." { String::new() } else { field },
            line: line_of(inner.span()),
            message: one_line(inner.message()),
        }
    })
}

/// Value parser for a [`clap::ValueEnum`] whose error lists the known values on its first line:
/// the CLI reports only the first line of a parse error, where clap's own parser puts the
/// possible values on the second. Help and completions get the values as usual.
#[derive(Debug)]
pub struct OneOf<E>(PhantomData<E>);

impl<E: ValueEnum + Clone + Send + Sync + 'static> OneOf<E> {
    /// The parser.
    pub fn new() -> Self {
        OneOf(PhantomData)
    }

    /// The parser giving the value's canonical name (`monte-carlo` → `monte_carlo`), for a
    /// setting kept as text until its setter checks it.
    pub fn names() -> clap::builder::MapValueParser<Self, fn(E) -> String> {
        Self::new().map(|v: E| {
            v.to_possible_value()
                .map(|p| p.get_name().to_string())
                .unwrap_or_default()
        })
    }
}

impl<E> Default for OneOf<E> {
    fn default() -> Self {
        OneOf(PhantomData)
    }
}

impl<E> Clone for OneOf<E> {
    fn clone(&self) -> Self {
        OneOf(PhantomData)
    }
}

impl<E: ValueEnum + Clone + Send + Sync + 'static> TypedValueParser for OneOf<E> {
    type Value = E;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &OsStr,
    ) -> Result<E, clap::Error> {
        let text = value.to_string_lossy();
        E::from_str(&text, false).map_err(|_| {
            let known: Vec<String> = E::value_variants()
                .iter()
                .filter_map(ValueEnum::to_possible_value)
                .filter(|v| !v.is_hide_set())
                .map(|v| v.get_name().to_string())
                .collect();
            let arg = arg.map_or_else(|| "...".to_string(), |a| a.to_string());
            clap::Error::raw(
                ErrorKind::InvalidValue,
                format!(
                    "invalid value '{text}' for '{arg}' (known: {})\n",
                    known.join(", ")
                ),
            )
            .with_cmd(cmd)
        })
    }

    fn possible_values(&self) -> Option<Box<dyn Iterator<Item = PossibleValue> + '_>> {
        Some(Box::new(
            E::value_variants()
                .iter()
                .filter_map(ValueEnum::to_possible_value),
        ))
    }
}

/// The files this process read as inputs (a problem file, records, measurements, a tuned
/// config, shard files, field logs, the files a worker's command names), by identity: the
/// device and inode of the file a path resolves to. An output must never be one of them
/// (`output` asks [`input_at`] before any work and again before it writes), however the
/// two paths are spelt: `x.toml`, `./x.toml`, a symbolic link or a hard link to it.
///
/// Noted where a user's file is opened as an input, and by the command line for every path
/// its input flags name before any work starts, so that an input read late (a field log
/// being followed, records streamed during the Monte Carlo) is known from the start.
static INPUTS: std::sync::Mutex<Vec<InputFile>> = std::sync::Mutex::new(Vec::new());

#[derive(Debug)]
struct InputFile {
    dev: u64,
    ino: u64,
    path: PathBuf,
}

/// Note `path` as an input of this process, if it names an existing file (following
/// links). A path that does not exist (yet) is not noted: no output can be it and survive
/// the check that it is missing or replaceable.
pub fn note_input(path: &Path) {
    use std::os::unix::fs::MetadataExt;
    if let Ok(m) = std::fs::metadata(path) {
        let mut inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
        // A noted input removed since may have left its inode to this file: that entry's
        // path no longer leads here, so it must not stand in for this one.
        inputs.retain(|f| !(f.dev == m.dev() && f.ino == m.ino()) || leads_to(&f.path, &m));
        if !inputs.iter().any(|f| f.dev == m.dev() && f.ino == m.ino()) {
            inputs.push(InputFile {
                dev: m.dev(),
                ino: m.ino(),
                path: path.to_path_buf(),
            });
        }
    }
}

/// The input (as it was named) that `path` resolves to the same file as, if any.
pub fn input_at(path: &Path) -> Option<PathBuf> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(path).ok()?;
    let inputs = INPUTS.lock().unwrap_or_else(|e| e.into_inner());
    // An input whose path no longer leads to the file noted was removed or replaced: its
    // inode may since belong to another file (a library user's long process, tests).
    inputs
        .iter()
        .find(|f| f.dev == m.dev() && f.ino == m.ino() && leads_to(&f.path, &m))
        .map(|f| f.path.clone())
}

/// Whether `path` resolves (following links) to the file whose metadata is `m`.
fn leads_to(path: &Path, m: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::MetadataExt;
    std::fs::metadata(path).is_ok_and(|n| n.dev() == m.dev() && n.ino() == m.ino())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_input_removed_since_it_was_noted_protects_no_other_file() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("problem.toml");
        std::fs::write(&input, "x").unwrap();
        note_input(&input);
        assert_eq!(input_at(&input), Some(input.clone()));
        std::fs::remove_file(&input).unwrap();
        // A new file may get the removed one's inode; it is not the input.
        for k in 0..8 {
            let other = dir.path().join(format!("out{k}.xml"));
            std::fs::write(&other, "y").unwrap();
            assert_eq!(input_at(&other), None, "{}", other.display());
        }
    }

    #[test]
    fn a_file_that_took_a_removed_inputs_inode_is_protected_once_noted() {
        let dir = tempfile::tempdir().unwrap();
        // Remove and recreate until an inode comes back (ext4 and tmpfs reuse the last one
        // freed); the new file, noted as an input, must be found although an entry for its
        // inode under the old path was noted first.
        for k in 0..64 {
            let old = dir.path().join(format!("old{k}.toml"));
            std::fs::write(&old, "x").unwrap();
            note_input(&old);
            let ino = std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(&old).unwrap());
            std::fs::remove_file(&old).unwrap();
            let new = dir.path().join(format!("new{k}.toml"));
            std::fs::write(&new, "y").unwrap();
            note_input(&new);
            assert_eq!(input_at(&new), Some(new.clone()));
            let reused = std::os::unix::fs::MetadataExt::ino(&std::fs::metadata(&new).unwrap());
            if reused == ino {
                return;
            }
        }
    }
}

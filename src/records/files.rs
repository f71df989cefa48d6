//! Reading a set of records files into one experiment's sums: each file's format by its
//! extension, its layout checked against the others', its records streamed into the sums.

use std::path::{Path, PathBuf};

use super::rows::fits;
use super::{Layout, MAX_STEPS, RecordSink, StepSink};
use crate::input::FileError;
use crate::stats::Accumulator;

/// A recorded experiment read from files.
#[derive(Debug, Clone)]
pub struct Recorded {
    /// What the records hold.
    pub layout: Layout,
    /// Runs N.
    pub runs: usize,
    /// Steps per run T.
    pub steps: usize,
    /// Their sums.
    pub sums: Accumulator,
}

/// The format of a records file, by its extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Format {
    Csv,
    Npz,
    Npy,
    Jsonl,
}

pub(super) fn format_of(path: &Path) -> Result<Format, FileError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("csv") => Ok(Format::Csv),
        Some("npz") => Ok(Format::Npz),
        Some("npy") => Ok(Format::Npy),
        Some("jsonl") | Some("ndjson") => Ok(Format::Jsonl),
        _ => Err(FileError::new(
            path,
            "",
            "not a records file: expected .csv, .npz, .npy or .jsonl (see docs/src/records.md)",
        )),
    }
}

/// Read the records in `paths` (CSV, NumPy, JSON Lines, by extension; several `.npy` files
/// are one set of arrays, each named after its quantity) into one experiment's sums, with
/// `lags(T)` whiteness lags for records of T steps. Every file is read
/// whole, and twice (once for its layout and length, once for its numbers), before any sum
/// is returned; an error names the file, the row or array, and the field.
pub fn read_files(paths: &[PathBuf], lags: &dyn Fn(usize) -> usize) -> Result<Recorded, FileError> {
    paths.iter().for_each(|p| crate::input::note_input(p));
    let (layout, steps) = scan_files(paths)?;
    let mut sink = RecordSink::new(&layout, steps, lags(steps));
    feed_files(paths, &layout, steps, &mut sink)?;
    let runs = sink.runs();
    let sums = sink
        .finish()
        .map_err(|e| FileError::new(&paths[0], "", e.to_string()))?;
    Ok(Recorded {
        layout,
        runs,
        steps,
        sums,
    })
}

/// The `.npy` files of one set of arrays form one source; every other file is its own.
fn sources(paths: &[PathBuf]) -> Result<Vec<Vec<PathBuf>>, FileError> {
    let mut sources: Vec<Vec<PathBuf>> = Vec::new();
    let mut npy: Vec<PathBuf> = Vec::new();
    for p in paths {
        match format_of(p)? {
            Format::Npy => npy.push(p.clone()),
            _ => sources.push(vec![p.clone()]),
        }
    }
    if !npy.is_empty() {
        sources.push(npy);
    }
    Ok(sources)
}

/// Read the records files `paths` once for what they hold: the layout they share and the
/// number of steps per run (at most [`MAX_STEPS`]). An error names the file that does not
/// fit the first.
pub fn scan_files(paths: &[PathBuf]) -> Result<(Layout, usize), FileError> {
    if paths.is_empty() {
        return Err(FileError::new(
            Path::new("--records"),
            "",
            "no records files given",
        ));
    }
    let sources = sources(paths)?;
    let mut scanned: Vec<(Layout, usize)> = Vec::new();
    for src in &sources {
        scanned.push(scan(src)?);
    }
    let (layout, steps) = scanned[0].clone();
    for (src, (l, t)) in sources.iter().zip(&scanned).skip(1) {
        if *t != steps {
            return Err(FileError::new(
                &src[0],
                "step",
                format!(
                    "{t} steps per run, but {} has {steps}",
                    sources[0][0].display()
                ),
            ));
        }
        fits(l, &layout).map_err(|e| {
            FileError::new(&src[0], "", format!("{e} (in {})", sources[0][0].display()))
        })?;
    }
    if steps > MAX_STEPS {
        return Err(FileError::new(
            &sources[0][0],
            "step",
            format!("{steps} steps per run, above the limit of {MAX_STEPS}"),
        ));
    }
    Ok((layout, steps))
}

/// Stream the records files `paths`, of the `layout` and `steps` [`scan_files`] found, into
/// `sink`, file by file in order.
pub fn feed_files<E: std::error::Error>(
    paths: &[PathBuf],
    layout: &Layout,
    steps: usize,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    for src in sources(paths)? {
        feed(&src, layout, steps, 0, sink)?;
    }
    Ok(())
}

/// Stream the records file `path` (CSV, NumPy `.npz` or JSON Lines) into `sink`, an
/// experiment of `layout` with `steps` steps; a NumPy file's runs are numbered from
/// `first_run`.
pub fn feed_file<E: std::error::Error>(
    path: &Path,
    layout: &Layout,
    steps: usize,
    first_run: usize,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    feed(&[path.to_path_buf()], layout, steps, first_run, sink)
}

/// The layout and the number of steps of one source.
fn scan(src: &[PathBuf]) -> Result<(Layout, usize), FileError> {
    match format_of(&src[0])? {
        Format::Csv => super::csv::scan(&src[0]),
        Format::Jsonl => super::json::scan(&src[0]),
        Format::Npz | Format::Npy => {
            let arrays = super::npy::Arrays::read(src)?;
            Ok((arrays.layout.clone(), arrays.steps))
        }
    }
}

/// Stream one source's records into `sink`; NumPy runs are numbered from `first_run`.
pub(super) fn feed<E: std::error::Error>(
    src: &[PathBuf],
    layout: &Layout,
    steps: usize,
    first_run: usize,
    sink: &mut dyn StepSink<Error = E>,
) -> Result<(), FileError> {
    match format_of(&src[0])? {
        Format::Csv => super::csv::feed(&src[0], layout, sink),
        Format::Jsonl => super::json::feed(&src[0], layout, sink),
        Format::Npz | Format::Npy => {
            let arrays = super::npy::Arrays::read(src)?;
            arrays.feed(layout, steps, first_run, sink)
        }
    }
}

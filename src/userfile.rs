//! Opening and reading files a user or a worker names (records, measurement records, field
//! logs, problem files), with the limits that keep memory and time bounded whatever the
//! file holds.
//!
//! Every reader of such a file goes through [`open`], so the checks hold in one place:
//!
//! - Only a regular file is read. The open does not block (`O_NONBLOCK`), and the kind is
//!   taken from the opened descriptor (`fstat`), not from the path: a FIFO without a writer
//!   is refused instead of hanging for ever, and `/dev/zero`, a directory or a symlink to a
//!   device are refused instead of being read without end.
//! - A line of text (a CSV row, quoted cells included, or a JSON Lines line) is at most
//!   [`MAX_LINE`] bytes ([`LineCapped`]); a CSV header has at most [`MAX_COLUMNS`] columns.
//! - A file read whole (a problem file) is at most [`MAX_TEXT`] bytes.
//! - NumPy arrays are held in memory: their declared size is checked against the bytes the
//!   file really has ([`npy_fits`]), and an `.npz` archive may expand to at most
//!   [`npz_budget`] bytes of numbers, before anything is allocated.
//!
//! The limits are documented in docs/external.md, docs/measurements.md and docs/fieldlog.md.

use std::fs::File;
use std::io::{self, Read};
use std::path::Path;

use crate::input::FileError;

/// Longest line of a text file, in bytes (8 MiB): a CSV row (a quoted cell may hold line
/// breaks: the whole row counts) or a JSON Lines line. A full 300 × 300 covariance in
/// full precision is about 2 MB. Parsed JSON takes up to ~30 bytes per byte of a list of
/// one-digit numbers (a 16 MiB line took 500 MB), so a longer line would let one line cost
/// gigabytes.
pub const MAX_LINE: usize = 8 << 20;

/// Most columns in a CSV header: a full covariance of 1000 states.
pub const MAX_COLUMNS: usize = 1_000_000;

/// Largest file read whole as text (a problem file, a tuned config), in bytes (16 MiB).
pub const MAX_TEXT: u64 = 16 << 20;

/// What an `.npz` archive's arrays may expand to in memory (as float64) whatever the
/// archive's size, in bytes (128 MiB).
pub const NPZ_FLOOR: u64 = 128 << 20;

/// How many times its size on disk an `.npz` archive's arrays may expand to in memory (as
/// float64), above [`NPZ_FLOOR`]. A deflated archive of zeros expands ~1000×: the limit is
/// what keeps a 1.6 MB file from taking gigabytes.
pub const NPZ_RATIO: u64 = 64;

/// The message for anything but a regular file.
pub const NOT_REGULAR: &str = "not a regular file (a directory, FIFO, socket or device)";

/// `bytes` as a short size (`16 MiB`, `3.2 GB`) for messages.
pub fn size_text(bytes: u64) -> String {
    const MIB: u64 = 1 << 20;
    if bytes >= MIB && bytes.is_multiple_of(MIB) {
        format!("{} MiB", bytes / MIB)
    } else if bytes >= 1_000_000 {
        format!("{:.1} MB", bytes as f64 / 1e6)
    } else {
        format!("{bytes} bytes")
    }
}

/// Open `path` to read: a regular file only, checked on the opened descriptor. The open
/// does not block on a FIFO. The error is an [`io::Error`] (its kind tells a missing file),
/// for callers that treat "not there yet" apart; [`open`] names the file.
pub fn open_io(path: &Path) -> io::Result<File> {
    let mut options = std::fs::OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path)?;
    if !file.metadata()?.is_file() {
        return Err(io::Error::other(NOT_REGULAR));
    }
    Ok(file)
}

/// Open `path` to read ([`open_io`]); the error names the file.
pub fn open(path: &Path) -> Result<File, FileError> {
    open_io(path).map_err(|e| cannot_read(path, &e))
}

/// `cannot read: <why>` for `path`.
pub fn cannot_read(path: &Path, e: &io::Error) -> FileError {
    FileError::new(path, "", format!("cannot read: {e}"))
}

/// The length of the opened file `file` (its `fstat`, not the path's), in bytes.
pub fn length(path: &Path, file: &File) -> Result<u64, FileError> {
    file.metadata()
        .map(|m| m.len())
        .map_err(|e| cannot_read(path, &e))
}

/// Read `path` whole as UTF-8 text, at most [`MAX_TEXT`] bytes; the error names the file.
pub fn read_text(path: &Path) -> Result<String, FileError> {
    read_text_at_most(path, MAX_TEXT)
}

/// [`read_text`] with a limit of `limit` bytes (a shard file's sums can outgrow a problem
/// file's limit).
pub fn read_text_at_most(path: &Path, limit: u64) -> Result<String, FileError> {
    let file = open(path)?;
    // A text file read whole is a user's input (a problem file, a config, a shard file).
    crate::input::note_input(path);
    let len = length(path, &file)?;
    let too_large = || {
        FileError::new(
            path,
            "",
            format!("larger than the limit of {}", size_text(limit)),
        )
    };
    if len > limit {
        return Err(too_large());
    }
    let mut bytes = Vec::with_capacity(len as usize);
    // A file still growing may be longer than its length was: read one byte past the limit
    // to tell.
    file.take(limit.saturating_add(1))
        .read_to_end(&mut bytes)
        .map_err(|e| cannot_read(path, &e))?;
    if bytes.len() as u64 > limit {
        return Err(too_large());
    }
    String::from_utf8(bytes).map_err(|_| FileError::new(path, "", "not UTF-8 text"))
}

/// The error [`LineCapped`] returns for a line longer than its limit; its text is the whole
/// message.
pub fn line_too_long(limit: usize) -> io::Error {
    io::Error::new(
        io::ErrorKind::InvalidData,
        format!(
            "a line longer than the limit of {}",
            size_text(limit as u64)
        ),
    )
}

/// A reader that fails (with [`line_too_long`]) once more than `limit` bytes pass without
/// a line break, so a line-by-line reader above it (a `BufRead`'s lines, the CSV reader)
/// never holds more than about `limit` bytes of one line. For CSV, a line break inside a
/// quoted cell does not end the row, and the whole row counts.
pub struct LineCapped<R> {
    inner: R,
    limit: usize,
    /// Bytes since the last line break that ended a line.
    run: usize,
    /// Whether `"` opens quoted cells whose line breaks do not end the row (CSV).
    csv: bool,
    /// Inside a quoted CSV cell.
    quoted: bool,
}

impl<R: Read> LineCapped<R> {
    /// Lines of JSON Lines or other text without quoting, at most [`MAX_LINE`] bytes.
    pub fn text(inner: R) -> Self {
        Self::with_limit(inner, MAX_LINE, false)
    }

    /// Rows of CSV, at most [`MAX_LINE`] bytes each (quoted line breaks included).
    pub fn csv(inner: R) -> Self {
        Self::with_limit(inner, MAX_LINE, true)
    }

    /// Lines of at most `limit` bytes; `csv`: quoted line breaks do not end a row.
    pub fn with_limit(inner: R, limit: usize, csv: bool) -> Self {
        LineCapped {
            inner,
            limit,
            run: 0,
            csv,
            quoted: false,
        }
    }
}

impl<R: Read> Read for LineCapped<R> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        if self.run > self.limit {
            return Err(line_too_long(self.limit));
        }
        let n = self.inner.read(buf)?;
        for (i, &b) in buf[..n].iter().enumerate() {
            match b {
                b'"' if self.csv => {
                    // `""` inside a quoted cell toggles twice: the cell stays quoted.
                    self.quoted = !self.quoted;
                    self.run += 1;
                }
                b'\n' if !self.quoted => self.run = 0,
                _ => self.run += 1,
            }
            if self.run > self.limit {
                // Hand on only the bytes within the limit, so the reader above never sees
                // the end of the long line: it gets the error on its next read.
                return if i == 0 {
                    Err(line_too_long(self.limit))
                } else {
                    Ok(i)
                };
            }
        }
        Ok(n)
    }
}

/// Open `path` ([`open`]) for line-by-line reading under [`MAX_LINE`].
pub fn text_lines(path: &Path) -> Result<io::BufReader<LineCapped<File>>, FileError> {
    Ok(io::BufReader::new(LineCapped::text(open(path)?)))
}

/// A CSV reader of `path` ([`open`]), rows under [`MAX_LINE`]; `builder` sets the dialect.
pub fn csv_reader(
    path: &Path,
    builder: &csv::ReaderBuilder,
) -> Result<csv::Reader<LineCapped<File>>, FileError> {
    Ok(builder.from_reader(LineCapped::csv(open(path)?)))
}

/// Refuse a CSV header of more than [`MAX_COLUMNS`] columns.
pub fn check_columns(path: &Path, columns: usize) -> Result<(), FileError> {
    if columns > MAX_COLUMNS {
        let mut e = FileError::new(
            path,
            "header",
            format!("{columns} columns, above the limit of {MAX_COLUMNS}"),
        );
        e.line = Some(1);
        return Err(e);
    }
    Ok(())
}

/// Whether an array of `elements` items of `itemsize` bytes fits in `available` bytes (the
/// bytes of the file, or of the archive entry, that hold it): a header's shape is a claim,
/// and the data must be there before memory is reserved for it.
pub fn npy_fits(elements: u64, itemsize: u64, available: u64) -> bool {
    elements
        .checked_mul(itemsize)
        .is_some_and(|bytes| bytes <= available)
}

/// The bytes of float64 numbers the arrays of an `.npz` archive of `archive_len` bytes may
/// expand to: [`NPZ_RATIO`] times its size, and at least [`NPZ_FLOOR`].
pub fn npz_budget(archive_len: u64) -> u64 {
    archive_len.saturating_mul(NPZ_RATIO).max(NPZ_FLOOR)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_line_longer_than_the_limit_fails_and_shorter_ones_pass() {
        let text = b"ab\ncdef\n".repeat(4);
        let mut out = String::new();
        LineCapped::with_limit(&text[..], 4, false)
            .read_to_string(&mut out)
            .unwrap();
        assert_eq!(out.as_bytes(), &text[..]);
        let long = [b'x'; 100];
        let mut r = io::BufReader::with_capacity(8, LineCapped::with_limit(&long[..], 10, false));
        let mut sink = Vec::new();
        let e = io::BufRead::read_until(&mut r, b'\n', &mut sink).unwrap_err();
        assert!(e.to_string().contains("longer than the limit"), "{e}");
        assert!(sink.len() <= 10);
    }

    #[test]
    fn a_quoted_csv_line_break_does_not_end_the_row() {
        let text = b"\"a\nb\nc\nd\"\n";
        let mut out = Vec::new();
        let e = LineCapped::with_limit(&text[..], 4, true).read_to_end(&mut out);
        assert!(e.is_err());
        assert!(out.len() <= 4);
        let mut ok = Vec::new();
        LineCapped::with_limit(&text[..], 4, false)
            .read_to_end(&mut ok)
            .unwrap();
        assert_eq!(ok, text);
    }

    #[test]
    fn a_long_line_ending_within_one_read_is_still_refused() {
        let text = b"0123456789\nab\n";
        let mut r = io::BufReader::new(LineCapped::with_limit(&text[..], 5, false));
        let mut line = String::new();
        assert!(io::BufRead::read_line(&mut r, &mut line).is_err());
    }

    #[test]
    fn the_npz_budget_has_a_floor_and_a_ratio() {
        assert_eq!(npz_budget(1000), NPZ_FLOOR);
        assert_eq!(npz_budget(1 << 30), (1 << 30) * NPZ_RATIO);
        assert!(npy_fits(10, 8, 80));
        assert!(!npy_fits(11, 8, 80));
        assert!(!npy_fits(u64::MAX, 8, u64::MAX));
    }
}

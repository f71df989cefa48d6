//! NumPy arrays read from an `.npz` archive or `.npy` files: the header checked, the data
//! read as f64 in C order within a budget; nothing about what the arrays mean.

use std::io::Read;
use std::path::{Path, PathBuf};

use crate::input::FileError;
use crate::userfile;

/// Largest array the reader accepts, in elements: 2³¹ doubles are 16 GiB.
const MAX_ELEMENTS: u64 = 1 << 31;

/// Longest `.npy` header accepted, in bytes (NumPy's own reader stops at 10 000): the
/// header's length is a claim, read before anything else.
const MAX_HEADER: u64 = 1 << 20;

/// The bytes an array's data may take in memory (as float64) while a set of arrays is read:
/// `userfile::npz_budget` of the files' size on disk, spent array by array.
struct Budget {
    left: u64,
    total: u64,
}

/// A stream whose first bytes were read to check them, put back in front.
type Rejoined<R> = std::io::Chain<std::io::Cursor<Vec<u8>>, R>;

/// Why a `.npy` stream was refused before its data was read.
#[derive(Debug, thiserror::Error)]
enum HeaderError {
    /// The stream could not be read (the reader's words, on one line).
    #[error("cannot read: {0}")]
    Unreadable(String),
    /// A header longer than [`MAX_HEADER`] or than the data.
    #[error(
        "not a .npy file: a header of {len} bytes (the limit is {}, the data has {available} bytes)",
        userfile::size_text(MAX_HEADER)
    )]
    LongHeader {
        /// The length the pre-header claims.
        len: u64,
        /// Bytes there are.
        available: u64,
    },
    /// What NumPy's format does not allow (the reader's words, on one line).
    #[error("not a .npy file: {0}")]
    NotNpy(String),
}

/// Check the pre-header of a `.npy` stream (magic, version, header length) against the
/// `available` bytes before the NumPy reader reserves memory for the header, and hand the
/// stream on whole.
fn checked_npy<R: Read>(
    mut r: R,
    available: u64,
) -> Result<npyz::NpyFile<Rejoined<R>>, HeaderError> {
    let mut head = Vec::with_capacity(12);
    (&mut r)
        .take(12)
        .read_to_end(&mut head)
        .map_err(|e| HeaderError::Unreadable(one_line(&e)))?;
    if head.len() >= 10 && head.starts_with(b"\x93NUMPY") {
        let len = match head[6] {
            1 => u64::from(u16::from_le_bytes([head[8], head[9]])),
            _ if head.len() == 12 => {
                u64::from(u32::from_le_bytes([head[8], head[9], head[10], head[11]]))
            }
            _ => 0,
        };
        if len > MAX_HEADER.min(available) {
            return Err(HeaderError::LongHeader { len, available });
        }
    }
    npyz::NpyFile::new(std::io::Cursor::new(head).chain(r))
        .map_err(|e| HeaderError::NotNpy(one_line(&e)))
}

/// Read one array, whose data lies in the `available` bytes of its file or archive entry,
/// spending its size as float64 from `budget`.
fn read_array<R: Read>(
    file: &Path,
    name: &str,
    npy: npyz::NpyFile<R>,
    available: u64,
    budget: &mut Budget,
) -> Result<(Vec<usize>, Vec<f64>), FileError> {
    let err = |m: String| FileError::new(file, format!("array {name}"), m);
    // npyz's own `len()` wraps on absurd shapes ((2³², 2³²) has "0" elements): count
    // them here, and trust no index into the data before the count is known to be small.
    let len = npy
        .shape()
        .iter()
        .try_fold(1u64, |n, &d| n.checked_mul(d))
        .filter(|&n| n <= MAX_ELEMENTS)
        .ok_or_else(|| {
            err(format!(
                "shape {:?}: above the limit of {MAX_ELEMENTS} elements",
                npy.shape()
            ))
        })?;
    let shape: Vec<usize> = npy.shape().iter().map(|&d| d as usize).collect();
    let order = npy.order();
    let dtype = npy.dtype().descr();
    let itemsize = npy.dtype().num_bytes().unwrap_or(usize::MAX) as u64;
    // The header's shape is a claim: the data must be there, and fit the budget, before
    // memory is reserved for it.
    if !userfile::npy_fits(len, itemsize, available) {
        return Err(err(format!(
            "truncated: shape {shape:?} of {itemsize}-byte numbers needs more than the {available} bytes there are"
        )));
    }
    // A Fortran-order array is reordered into a copy: it takes its size twice.
    let copies = if order == npyz::Order::C || shape.len() < 2 {
        1
    } else {
        2
    };
    let cost = len * 8 * copies;
    if cost > budget.left {
        return Err(err(format!(
            "{} as float64: the arrays expand beyond the limit of {} for this file (docs/src/records.md, Limits)",
            userfile::size_text(len * 8),
            userfile::size_text(budget.total)
        )));
    }
    budget.left -= cost;
    let len = len as usize;
    // The common case, little-endian float64, read in blocks straight into the numbers:
    // element by element, the zip reader's checksum and the buffering cost more than them.
    if dtype == "'<f8'" || (dtype == "'=f8'" && cfg!(target_endian = "little")) {
        let data = read_le_f64(npy.into_inner(), len, &err)?;
        return Ok((shape.clone(), c_order(&shape, order, data, &err)?));
    }
    macro_rules! try_types {
        ($npy:expr, $($t:ty),*) => {{
            let npy = $npy;
            $(
                let npy = match npy.try_data::<$t>() {
                    Ok(reader) => {
                        let mut out = numbers_for(len, &err)?;
                        for v in reader {
                            out.push(v.map_err(|e| err(format!("cannot read: {}", one_line(&e))))? as f64);
                        }
                        return Ok((shape.clone(), c_order(&shape, order, out, &err)?));
                    }
                    Err(npy) => npy,
                };
            )*
            drop(npy);
        }};
    }
    try_types!(npy, f64, f32, i64, i32, i16, i8, u64, u32, u16, u8);
    Err(err(format!(
        "dtype {dtype} is not a real number type (use float64)"
    )))
}

/// `len` little-endian float64 numbers from `reader`, read in blocks; `err` names the
/// array in an error.
fn read_le_f64(
    reader: impl Read,
    len: usize,
    err: &dyn Fn(String) -> FileError,
) -> Result<Vec<f64>, FileError> {
    let mut data = numbers_for(len, err)?;
    let mut reader = reader.take(len as u64 * 8);
    let mut block = vec![0u8; 1 << 16];
    let mut filled = 0;
    loop {
        let n = match reader.read(&mut block[filled..]) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(err(format!("cannot read: {}", one_line(&e)))),
        };
        filled += n;
        let whole = filled / 8 * 8;
        data.extend(
            block[..whole]
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes"))),
        );
        block.copy_within(whole..filled, 0);
        filled -= whole;
    }
    if data.len() < len {
        return Err(err(format!(
            "truncated: {} bytes of data for {len} float64 numbers",
            data.len() * 8 + filled
        )));
    }
    Ok(data)
}

/// Room for `len` numbers, reserved fallibly: an array that passes every check on its file
/// (a sparse file's holes count as data) may still not fit in this machine's memory, which
/// is refused in one line rather than aborting the process.
fn numbers_for(len: usize, err: &dyn Fn(String) -> FileError) -> Result<Vec<f64>, FileError> {
    let mut v = Vec::new();
    v.try_reserve_exact(len).map_err(|_| {
        err(format!(
            "{} as float64 do not fit in memory",
            userfile::size_text((len as u64).saturating_mul(8))
        ))
    })?;
    Ok(v)
}

/// An error of the NumPy or zip reader on one line: a header the Python-literal parser
/// refuses comes with a drawing of where (`--> 1:17`, the header, a caret, `= expected
/// value`), of which the position and the expectation are kept.
fn one_line(e: &impl std::fmt::Display) -> String {
    let text = e.to_string();
    let kept: Vec<&str> = text
        .lines()
        .map(str::trim)
        .filter(|l| {
            let drawing = l.starts_with('|')
                || l.split_once(" |")
                    .is_some_and(|(n, _)| n.parse::<u64>().is_ok());
            !l.is_empty() && !drawing
        })
        .map(|l| l.strip_prefix("= ").unwrap_or(l))
        .collect();
    kept.join(" ")
}

/// `data` in C order, given in `order`.
fn c_order(
    shape: &[usize],
    order: npyz::Order,
    data: Vec<f64>,
    err: &dyn Fn(String) -> FileError,
) -> Result<Vec<f64>, FileError> {
    if order == npyz::Order::C || shape.len() < 2 {
        return Ok(data);
    }
    let mut out = numbers_for(data.len(), err)?;
    out.resize(data.len(), 0.0);
    let mut idx = vec![0usize; shape.len()];
    for v in out.iter_mut() {
        // Fortran offset of the current C-order multi-index.
        let mut off = 0;
        let mut stride = 1;
        for (i, &d) in idx.iter().zip(shape) {
            off += i * stride;
            stride *= d;
        }
        *v = data[off];
        for a in (0..shape.len()).rev() {
            idx[a] += 1;
            if idx[a] < shape[a] {
                break;
            }
            idx[a] = 0;
        }
    }
    Ok(out)
}

/// A NumPy array as read: its name, shape and data (f64, C order).
pub(crate) type RawArray = (String, Vec<usize>, Vec<f64>);

/// The arrays of an `.npz` archive or of a set of `.npy` files (each named after its file
/// stem), by name, with their shapes and their data as f64 in C order; nothing about what they
/// mean is checked here. `paths` is not empty.
pub(crate) fn read_raw(paths: &[PathBuf]) -> Result<Vec<RawArray>, FileError> {
    let file = paths[0].clone();
    let mut raw: Vec<RawArray> = Vec::new();
    let is_npz = paths.len() == 1
        && file
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("npz"));
    if is_npz {
        let f = userfile::open(&file)?;
        let archive_len = userfile::length(&file, &f)?;
        let total = userfile::npz_budget(archive_len);
        let mut budget = Budget { left: total, total };
        let mut archive = zip::ZipArchive::new(std::io::BufReader::new(f)).map_err(|e| {
            FileError::new(&file, "", format!("not an .npz archive: {}", one_line(&e)))
        })?;
        // NumPy's reading: every entry named `*.npy` is an array of that name.
        let names: Vec<String> = archive
            .file_names()
            .filter_map(npyz::npz::array_name_from_file_name)
            .map(str::to_string)
            .collect();
        for name in names {
            let at = |m: String| FileError::new(&file, format!("array {name}"), m);
            let entry = archive
                .by_name(&npyz::npz::file_name_from_array_name(&name))
                .map_err(|e| at(format!("cannot read: {}", one_line(&e))))?;
            // The entry's size is the zip's claim; reading stops at the data really there.
            let available = entry.size();
            let npy = checked_npy(entry, available).map_err(|e| at(e.to_string()))?;
            let (shape, data) = read_array(&file, &name, npy, available, &mut budget)?;
            raw.push((name, shape, data));
        }
    } else {
        let mut opened = Vec::new();
        for p in paths {
            let f = userfile::open(p)?;
            let len = userfile::length(p, &f)?;
            opened.push((p, f, len));
        }
        let total = userfile::npz_budget(opened.iter().map(|(_, _, l)| *l).sum());
        let mut budget = Budget { left: total, total };
        for (p, f, len) in opened {
            let name = p
                .file_stem()
                .and_then(|s| s.to_str())
                .unwrap_or_default()
                .to_string();
            let npy = checked_npy(std::io::BufReader::new(f), len)
                .map_err(|e| FileError::new(p, "", e.to_string()))?;
            let (shape, data) = read_array(p, &name, npy, len, &mut budget)?;
            if raw.iter().any(|(n, _, _)| *n == name) {
                return Err(FileError::new(p, format!("array {name}"), "given twice"));
            }
            raw.push((name, shape, data));
        }
    }
    Ok(raw)
}

//! A record's bytes as `simulate` writes them: CSV, JSON Lines or NumPy, by the path's
//! extension, in the layout the readers beside it take back.

use std::fmt::Write as _;
use std::path::Path;

use npyz::WriterBuilder;

use crate::input::FileError;

/// The bytes of a record (by `path`'s extension: CSV, JSON Lines or `.npy`) holding `rows`
/// named `prefix_1 … prefix_d` (`z` for measurements, `x` for true states): one `Vec` per
/// sequence, T × d row-major. With `dt` (s), each step k's time `k · dt` beside it (a
/// `time` column or key; a `.npy` array has no room for it).
pub fn record_bytes(
    path: &Path,
    prefix: &str,
    d: usize,
    rows: &[&[f64]],
    dt: Option<f64>,
) -> Result<Vec<u8>, FileError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let num = |v: f64| {
        if v.is_nan() {
            String::new()
        } else {
            format!("{v}")
        }
    };
    match ext.as_deref() {
        Some("csv") => {
            let mut o = String::from(if dt.is_some() {
                "run,step,time"
            } else {
                "run,step"
            });
            for j in 1..=d {
                let _ = write!(o, ",{prefix}_{j}");
            }
            o.push('\n');
            for (r, seq) in rows.iter().enumerate() {
                for (k, row) in seq.chunks(d).enumerate() {
                    let _ = write!(o, "{r},{}", k + 1);
                    if let Some(dt) = dt {
                        let _ = write!(o, ",{}", (k + 1) as f64 * dt);
                    }
                    for v in row {
                        let _ = write!(o, ",{}", num(*v));
                    }
                    o.push('\n');
                }
            }
            Ok(o.into_bytes())
        }
        Some("jsonl") | Some("ndjson") => {
            let mut o = String::new();
            for (r, seq) in rows.iter().enumerate() {
                for (k, row) in seq.chunks(d).enumerate() {
                    let vals: Vec<String> = row
                        .iter()
                        .map(|v| {
                            if v.is_nan() {
                                "null".into()
                            } else {
                                format!("{v}")
                            }
                        })
                        .collect();
                    let time = dt.map_or_else(String::new, |dt| {
                        format!(", \"time\": {}", (k + 1) as f64 * dt)
                    });
                    let _ = writeln!(
                        o,
                        "{{\"run\": {r}, \"step\": {}{time}, \"{prefix}\": [{}]}}",
                        k + 1,
                        vals.join(", ")
                    );
                }
            }
            Ok(o.into_bytes())
        }
        Some("npy") => {
            let steps = rows.first().map_or(0, |s| s.len() / d.max(1));
            let shape = [rows.len() as u64, steps as u64, d as u64];
            let mut bytes = Vec::new();
            let mut w = npyz::WriteOptions::<f64>::new()
                .default_dtype()
                .shape(&shape)
                .writer(&mut bytes)
                .begin_nd()
                .map_err(|e| FileError::new(path, "", format!("cannot encode: {e}")))?;
            for seq in rows {
                w.extend(seq.iter().copied())
                    .map_err(|e| FileError::new(path, "", format!("cannot encode: {e}")))?;
            }
            w.finish()
                .map_err(|e| FileError::new(path, "", format!("cannot encode: {e}")))?;
            Ok(bytes)
        }
        _ => Err(FileError::new(
            path,
            "",
            "writes .csv, .jsonl or .npy (docs/src/measurements.md)",
        )),
    }
}

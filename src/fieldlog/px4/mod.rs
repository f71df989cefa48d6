//! PX4 ULog flight logs: the EKF2 innovations and their variances, per estimator instance.
//!
//! PX4 logs each channel's innovation (`estimator_innovations`) and its variance
//! (`estimator_innovation_variances`), the same message layout, one instance per EKF
//! (multi-EKF logs have several); releases before v1.11 log one topic `ekf2_innovations`
//! with `<name>_innov` beside `<name>_innov_var`. No cross-covariances are logged, so each
//! array element is its own channel with a one-degree-of-freedom NIS `ν²/S`.
//!
//! A logged row is a publication of the topic, not a fusion: a channel that was not fused
//! since the last row repeats its values, and one never fused sits at zero. So per channel,
//! in row order: a row with innovation and variance both 0 is idle; a non-finite value or a
//! variance ≤ 0 is invalid; a row whose (innovation, variance) are bit-identical to the
//! previous row's is a repeat; anything else is an update. The logger may sample the two
//! topics at different cycles: each innovations row is paired with the variances row of the
//! same `timestamp_sample`, or else the nearest within 50 ms (noted as approximate); such a
//! row's variance is from another filter cycle, so for it the innovation alone decides
//! whether it repeats.
//!
//! The file is read by [`super::ulog_walk`], which checks each message before the crate's
//! parser sees it (some damaged files panic or run away inside the crate).

mod ekf2;
mod info;

pub use ekf2::ParamAdvice;
pub use info::{EventKind, NotJudged, Px4Channel, Px4Event, Px4Info, Px4Instance};

use std::cell::Cell;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

use px4_ulog::stream_parser::model::FlattenedFieldType;
use px4_ulog::stream_parser::{DataMessage, LogParser};

use super::analysis::{Dropped, NisAnalyzer, SensorInfo, Update};
use super::ulog_walk::{Ending, walk};
use super::{LogSource, ReadOptions};
use crate::input::FileError;

const INNOVATIONS: &str = "estimator_innovations";
const VARIANCES: &str = "estimator_innovation_variances";
const LEGACY: &str = "ekf2_innovations";
const LAND: &str = "vehicle_land_detected";
/// Largest gap between an innovations row and the variances row it is paired with, µs.
const PAIR_WITHIN_US: u64 = 50_000;
/// Rows of the estimator topics kept in memory at most (about an hour at 100 Hz per
/// instance for three instances).
const MAX_ROWS: usize = 5_000_000;

/// The rows of one topic instance: time (µs) and the float fields, by name.
#[derive(Debug, Default)]
struct Topic {
    names: Vec<String>,
    times: Vec<u64>,
    values: Vec<Vec<f32>>,
}

/// Everything read from the file.
#[derive(Debug, Default)]
struct Read {
    topics: BTreeMap<(String, u8), Topic>,
    /// (time µs, landed).
    land: Vec<(u64, bool)>,
    rows: usize,
}

fn wanted(name: &str) -> bool {
    matches!(name, INNOVATIONS | VARIANCES | LEGACY)
}

fn read_file(path: &Path) -> Result<(Read, Ending), FileError> {
    check_magic(path)?;
    let mut out = Read::default();
    let too_many = Cell::new(false);
    let mut cb = |d: &DataMessage| {
        if too_many.get() {
            return;
        }
        let f = d.flattened_format;
        let name = f.message_name();
        // Field offsets count from the start of the payload, msg_id included.
        let data = d.data;
        let read_u64 = |off: u16| -> Option<u64> {
            let o = off as usize;
            data.get(o..o + 8)
                .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
        };
        if name == LAND {
            let ts = f
                .field_iter()
                .find(|x| x.flattened_field_name == "timestamp");
            let landed = f.field_iter().find(|x| x.flattened_field_name == "landed");
            if let (Some(ts), Some(l)) = (ts, landed)
                && let (Some(t), Some(&b)) = (read_u64(ts.offset), data.get(l.offset as usize))
            {
                out.land.push((t, b != 0));
            }
            return;
        }
        if !wanted(name) {
            return;
        }
        out.rows += 1;
        if out.rows > MAX_ROWS {
            too_many.set(true);
            return;
        }
        let topic = out
            .topics
            .entry((name.to_string(), d.multi_id.value()))
            .or_default();
        let floats: Vec<_> = f
            .field_iter()
            .filter(|x| x.field_type == FlattenedFieldType::Float)
            .filter(|x| !x.flattened_field_name.starts_with("_padding"))
            .collect();
        if topic.names.is_empty() {
            topic.names = floats
                .iter()
                .map(|x| x.flattened_field_name.clone())
                .collect();
        }
        let time_field = f
            .field_iter()
            .find(|x| x.flattened_field_name == "timestamp_sample")
            .or_else(|| {
                f.field_iter()
                    .find(|x| x.flattened_field_name == "timestamp")
            });
        let Some(t) = time_field.and_then(|x| read_u64(x.offset)) else {
            return;
        };
        let vals: Vec<f32> = floats
            .iter()
            .map(|x| {
                let o = x.offset as usize;
                data.get(o..o + 4).map_or(f32::NAN, |b| {
                    f32::from_le_bytes(b.try_into().expect("4 bytes"))
                })
            })
            .collect();
        if vals.len() == topic.names.len() {
            topic.times.push(t);
            topic.values.push(vals);
        }
    };
    let ending = {
        let mut parser = LogParser::default();
        parser.set_data_message_callback(&mut cb);
        walk(path, &mut parser, &|| too_many.get())?
    };
    if too_many.get() {
        return Err(FileError::new(
            path,
            "",
            format!("more than {MAX_ROWS} rows of the estimator topics"),
        ));
    }
    Ok((out, ending))
}

/// The 7 bytes every ULog file starts with (then a version byte and a 64-bit timestamp).
const MAGIC: [u8; 7] = [b'U', b'L', b'o', b'g', 0x01, 0x12, 0x35];

/// Refuse a file that does not start with the ULog header before the parser sees it: a
/// short file would otherwise read as a truncated log.
fn check_magic(path: &Path) -> Result<(), FileError> {
    use std::io::Read as _;
    let mut head = [0u8; 16];
    let mut file = crate::userfile::open_io(path)
        .map_err(|e| FileError::new(path, "", format!("cannot read: {e}")))?;
    let mut got = 0;
    while got < head.len() {
        match file.read(&mut head[got..]) {
            Ok(0) => break,
            Ok(n) => got += n,
            Err(e) => return Err(FileError::new(path, "", format!("cannot read: {e}"))),
        }
    }
    if got < head.len() || head[..7] != MAGIC {
        return Err(FileError::new(
            path,
            "",
            "not a ULog file (it does not start with the ULog header)",
        ));
    }
    Ok(())
}

/// Whether the vehicle is in the air at `t` (µs): the latest land-detector row at or
/// before `t` says not landed; before the first row, on the ground.
fn in_air(land: &[(u64, bool)], t: u64) -> bool {
    let i = land.partition_point(|r| r.0 <= t);
    i > 0 && !land[i - 1].1
}

/// One channel: the column of its innovation and of its variance.
struct Channel {
    name: String,
    innov: usize,
    var: usize,
}

/// The column of each name (the first, should a name repeat).
fn columns(names: &[String]) -> HashMap<&str, usize> {
    let mut at = HashMap::with_capacity(names.len());
    for (i, n) in names.iter().enumerate() {
        at.entry(n.as_str()).or_insert(i);
    }
    at
}

/// Channels of the legacy topic: `<base>_innov[j]` beside `<base>_innov_var[j]`.
fn legacy_channels(names: &[String]) -> Vec<Channel> {
    let at = columns(names);
    let mut out = Vec::new();
    for (i, n) in names.iter().enumerate() {
        let (stem, idx) = match n.find('[') {
            Some(p) => (&n[..p], &n[p..]),
            None => (n.as_str(), ""),
        };
        let Some(base) = stem.strip_suffix("_innov") else {
            continue;
        };
        let var_name = format!("{stem}_var{idx}");
        if let Some(&v) = at.get(var_name.as_str()) {
            out.push(Channel {
                name: format!("{base}{idx}"),
                innov: i,
                var: v,
            });
        }
    }
    out
}

/// For each innovations row, the index of its variances row (exact `timestamp_sample`, or
/// the nearest within 50 ms, the earlier on a tie) and whether it was exact.
fn pair(innov: &[u64], var: &[u64]) -> Vec<Option<(usize, bool)>> {
    let mut exact: HashMap<u64, usize> = HashMap::new();
    for (j, &t) in var.iter().enumerate() {
        exact.entry(t).or_insert(j);
    }
    let mut order: Vec<usize> = (0..var.len()).collect();
    order.sort_by_key(|&j| (var[j], j));
    innov
        .iter()
        .map(|&t| {
            if let Some(&j) = exact.get(&t) {
                return Some((j, true));
            }
            let p = order.partition_point(|&j| var[j] < t);
            let before = p.checked_sub(1).map(|q| order[q]);
            let after = order.get(p).copied();
            let best = match (before, after) {
                (Some(b), Some(a)) => {
                    if t - var[b] <= var[a] - t {
                        Some(b)
                    } else {
                        Some(a)
                    }
                }
                (b, a) => b.or(a),
            }?;
            (var[best].abs_diff(t) <= PAIR_WITHIN_US).then_some((best, false))
        })
        .collect()
}

/// Read a PX4 ULog file into `an`.
pub(super) fn read(
    path: &Path,
    options: &ReadOptions,
    an: &mut NisAnalyzer,
) -> Result<LogSource, FileError> {
    let (read, ending) = read_file(path)?;
    let mut source = LogSource::new(path, "px4-ulog");
    source.rows = read.rows;
    match ending {
        Ending::Complete => {}
        Ending::Truncated if options.allow_truncated => source
            .notes
            .push("the file is truncated: the data before the cut were judged".into()),
        Ending::Truncated => {
            return Err(FileError::new(
                path,
                "",
                "the file is truncated (it ends partway through a message); --allow-truncated judges the data before the cut",
            ));
        }
        Ending::Malformed(why) if options.allow_truncated => source.notes.push(format!(
            "a malformed message ({}) ends the readable data: what came before was judged",
            first_line(&why)
        )),
        Ending::Malformed(why) => {
            return Err(FileError::new(
                path,
                "",
                format!(
                    "a malformed message in the data ({}); --allow-truncated judges the data before it",
                    first_line(&why)
                ),
            ));
        }
    }
    let instances: Vec<u8> = read
        .topics
        .keys()
        .filter(|(n, _)| n == INNOVATIONS || n == LEGACY)
        .map(|(_, i)| *i)
        .collect();
    if instances.is_empty() {
        return Err(FileError::new(
            path,
            "",
            format!("no {INNOVATIONS} (with {VARIANCES}) or {LEGACY} data: nothing to judge"),
        ));
    }
    if options.in_air && read.land.is_empty() {
        return Err(FileError::new(
            path,
            "",
            format!("--in-air needs the {LAND} topic, which this log does not have"),
        ));
    }
    let t0 = read
        .topics
        .values()
        .filter_map(|t| t.times.iter().min())
        .min()
        .copied()
        .unwrap_or(0);
    for ((name, inst), topic) in &read.topics {
        let legacy = name == LEGACY;
        if !(legacy || name == INNOVATIONS) {
            continue;
        }
        let (channels, pairing, var_topic) = if legacy {
            let pairing: Vec<Option<(usize, bool)>> =
                (0..topic.times.len()).map(|r| Some((r, true))).collect();
            (legacy_channels(&topic.names), pairing, topic)
        } else {
            let Some(vt) = read.topics.get(&(VARIANCES.to_string(), *inst)) else {
                source.notes.push(format!(
                    "ekf{inst}: {INNOVATIONS} without {VARIANCES}: skipped"
                ));
                continue;
            };
            let var_at = columns(&vt.names);
            let channels = topic
                .names
                .iter()
                .enumerate()
                .filter(|(_, n)| *n != "timestamp" && *n != "timestamp_sample")
                .filter_map(|(i, n)| {
                    var_at.get(n.as_str()).map(|&v| Channel {
                        name: n.clone(),
                        innov: i,
                        var: v,
                    })
                })
                .collect();
            (channels, pair(&topic.times, &vt.times), vt)
        };
        let exact = pairing
            .iter()
            .filter(|p| matches!(p, Some((_, true))))
            .count();
        let near = pairing
            .iter()
            .filter(|p| matches!(p, Some((_, false))))
            .count();
        let unpaired = pairing.len() - exact - near;
        if legacy {
            source.notes.push(format!(
                "ekf{inst}: {} rows of {LEGACY} (innovations and variances in one message)",
                pairing.len()
            ));
        } else {
            source.notes.push(format!(
                "ekf{inst}: {} rows; {exact} paired with a variances row of the same timestamp_sample, {near} with the nearest within 50 ms, {unpaired} unpaired (dropped)",
                pairing.len()
            ));
        }
        for ch in channels {
            let i = an
                .sensor(SensorInfo {
                    name: format!("ekf{inst}.{}", ch.name),
                    components: vec![format!("ekf{inst}.{}", ch.name)],
                    group: format!("ekf{inst}"),
                })
                .map_err(|m| FileError::new(path, "", m))?;
            let mut dropped = Dropped::default();
            let mut prev: Option<(u32, u32)> = None;
            for (r, p) in pairing.iter().enumerate() {
                let Some((vr, exact)) = *p else { continue };
                let nu = topic.values[r][ch.innov];
                let s = var_topic.values[vr][ch.var];
                let bits = (nu.to_bits(), s.to_bits());
                let last = prev.replace(bits);
                // A variance paired by nearest time is from another filter cycle: a change
                // in it says nothing about a fusion, so the innovation alone decides.
                let repeat = last.is_some_and(|(n, v)| n == bits.0 && (v == bits.1 || !exact));
                if nu == 0.0 && s == 0.0 {
                    dropped.idle += 1;
                } else if !nu.is_finite() || !s.is_finite() || s <= 0.0 {
                    dropped.invalid += 1;
                } else if repeat {
                    dropped.repeats += 1;
                } else if options.in_air && !in_air(&read.land, topic.times[r]) {
                    dropped.on_ground += 1;
                } else {
                    let (nu, s) = (f64::from(nu), f64::from(s));
                    an.push(
                        i,
                        Update {
                            time: (topic.times[r].saturating_sub(t0)) as f64 * 1e-6,
                            nis: nu * nu / s,
                            dof: 1,
                            u: Some(vec![nu / s.sqrt()]),
                            sd: Some(vec![s.sqrt()]),
                        },
                    )
                    .map_err(|m| FileError::new(path, "", m))?;
                }
            }
            an.drop_rows(i, dropped);
        }
    }
    Ok(source)
}

fn first_line(s: &str) -> String {
    let l = s.lines().next().unwrap_or("");
    crate::records::shown_up_to(l, 120)
}

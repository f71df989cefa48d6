//! Reading the topics a PX4 log's estimators publish, its parameters and its release, in one
//! pass of [`super::super::ulog_walk`].

use std::cell::{Cell, RefCell};
use std::collections::BTreeMap;
use std::path::Path;

use px4_ulog::stream_parser::model::{FlattenedFieldType, InfoMessage, LogStage, ParameterMessage};
use px4_ulog::stream_parser::{DataMessage, LogParser};

use super::super::ulog_walk::{Ending, feed_ulog};
use crate::input::FileError;

pub(super) const INNOVATIONS: &str = "estimator_innovations";
pub(super) const VARIANCES: &str = "estimator_innovation_variances";
pub(super) const TEST_RATIOS: &str = "estimator_innovation_test_ratios";
pub(super) const LEGACY: &str = "ekf2_innovations";
pub(super) const AID_SRC: &str = "estimator_aid_src_";
pub(super) const LAND: &str = "vehicle_land_detected";
pub(super) const STATUS: &str = "estimator_status";
pub(super) const STATUS_FLAGS: &str = "estimator_status_flags";
pub(super) const SELECTOR: &str = "estimator_selector_status";
pub(super) const EKF2_TIMESTAMPS: &str = "ekf2_timestamps";
/// Topics of the sensors' own data, whose logged rate says how often a source can be fused.
pub(super) const SOURCE_TOPICS: [&str; 10] = [
    "vehicle_air_data",
    "vehicle_gps_position",
    "sensor_gps",
    "vehicle_magnetometer",
    "distance_sensor",
    "vehicle_optical_flow",
    "optical_flow",
    "vehicle_visual_odometry",
    "airspeed",
    "airspeed_validated",
];
/// Rows of the estimator topics kept in memory at most (about an hour at 100 Hz per
/// instance for three instances).
pub(super) const MAX_ROWS: usize = 5_000_000;

/// The rows of one topic instance: the time of each row (µs; `timestamp_sample` where the
/// topic has it), its `timestamp`, and the kept fields' values by name.
#[derive(Debug, Default)]
pub(super) struct Topic {
    pub names: Vec<String>,
    pub times: Vec<u64>,
    pub stamps: Vec<u64>,
    pub values: Vec<Vec<f64>>,
    /// The topic has a `timestamp_sample` field.
    pub sampled_time: bool,
}

impl Topic {
    /// The column of `name`, if the topic has it.
    pub fn column(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Rows per second over the topic's span (0 for fewer than two rows or no span).
    pub fn rate_hz(&self) -> f64 {
        let (Some(&a), Some(&b)) = (self.stamps.iter().min(), self.stamps.iter().max()) else {
            return 0.0;
        };
        per_second(self.stamps.len(), b.saturating_sub(a) as f64 * 1e-6).unwrap_or(0.0)
    }
}

/// The rate of `count` events whose first and last are `span` seconds apart: `count − 1`
/// intervals over the span (`None` for fewer than two events or no span). Every rate the
/// PX4 reader reports (a topic's logged rate, a source's, a channel's updates) is this.
pub(super) fn per_second(count: usize, span: f64) -> Option<f64> {
    (count > 1 && span > 0.0).then(|| (count - 1) as f64 / span)
}

/// Everything read from the file.
#[derive(Debug, Default)]
pub(super) struct Read {
    pub topics: BTreeMap<(String, u8), Topic>,
    /// Rows kept of every topic read.
    pub kept: usize,
    /// (rows, first, last timestamp µs) of the sensors' own topics, by name.
    pub sources: BTreeMap<String, (usize, u64, u64)>,
    pub rows: usize,
    /// The ULog header's timestamp, µs.
    pub header_us: u64,
    /// `ver_sw_release`.
    pub release: Option<u32>,
    /// Parameters at the start of the log.
    pub params: BTreeMap<String, f64>,
    /// Parameters changed in the data section: (the latest data timestamp before, name, value).
    pub param_changes: Vec<(u64, String, f64)>,
}

/// Which fields of topic `name` are kept (None: not a topic of interest).
fn keeps(name: &str) -> Option<fn(&str, &FlattenedFieldType) -> bool> {
    fn floats(f: &str, t: &FlattenedFieldType) -> bool {
        *t == FlattenedFieldType::Float && !f.starts_with("_padding")
    }
    fn aid(f: &str, t: &FlattenedFieldType) -> bool {
        !f.starts_with("_padding")
            && (matches!(t, FlattenedFieldType::Float | FlattenedFieldType::Double)
                || f.starts_with("fused")
                || f.starts_with("innovation_rejected")
                || f == "estimator_instance")
    }
    fn flags(f: &str, _: &FlattenedFieldType) -> bool {
        f.starts_with("cs_") || f == "control_mode_flags"
    }
    fn land(f: &str, _: &FlattenedFieldType) -> bool {
        f == "landed"
    }
    fn selector(f: &str, _: &FlattenedFieldType) -> bool {
        f == "primary_instance"
    }
    fn nothing(_: &str, _: &FlattenedFieldType) -> bool {
        false
    }
    Some(match name {
        INNOVATIONS | VARIANCES | TEST_RATIOS | LEGACY => floats,
        n if n.starts_with(AID_SRC) => aid,
        STATUS | STATUS_FLAGS => flags,
        LAND => land,
        SELECTOR => selector,
        EKF2_TIMESTAMPS => nothing,
        _ => return None,
    })
}

fn value_at(data: &[u8], off: u16, ty: &FlattenedFieldType) -> f64 {
    let o = off as usize;
    let get = |n: usize| data.get(o..o + n);
    let v = match ty {
        FlattenedFieldType::Float => {
            get(4).map(|b| f64::from(f32::from_le_bytes(b.try_into().expect("4"))))
        }
        FlattenedFieldType::Double => get(8).map(|b| f64::from_le_bytes(b.try_into().expect("8"))),
        FlattenedFieldType::UInt8 | FlattenedFieldType::Bool | FlattenedFieldType::Char => {
            get(1).map(|b| f64::from(b[0]))
        }
        FlattenedFieldType::Int8 => get(1).map(|b| f64::from(b[0] as i8)),
        FlattenedFieldType::UInt16 => {
            get(2).map(|b| f64::from(u16::from_le_bytes(b.try_into().expect("2"))))
        }
        FlattenedFieldType::Int16 => {
            get(2).map(|b| f64::from(i16::from_le_bytes(b.try_into().expect("2"))))
        }
        FlattenedFieldType::UInt32 => {
            get(4).map(|b| f64::from(u32::from_le_bytes(b.try_into().expect("4"))))
        }
        FlattenedFieldType::Int32 => {
            get(4).map(|b| f64::from(i32::from_le_bytes(b.try_into().expect("4"))))
        }
        FlattenedFieldType::UInt64 => {
            get(8).map(|b| u64::from_le_bytes(b.try_into().expect("8")) as f64)
        }
        FlattenedFieldType::Int64 => {
            get(8).map(|b| i64::from_le_bytes(b.try_into().expect("8")) as f64)
        }
    };
    v.unwrap_or(f64::NAN)
}

/// Whether a parameter is one the report uses.
fn estimator_param(name: &str) -> bool {
    name.starts_with("EKF2_") || name == "SYS_MC_EST_GROUP" || name == "SYS_EST_GROUP"
}

pub(super) fn read_file(path: &Path) -> Result<(Read, Ending), FileError> {
    let header_us = check_magic(path)?;
    let out = RefCell::new(Read {
        header_us,
        ..Read::default()
    });
    let too_many = Cell::new(false);
    let last_stamp = Cell::new(0u64);
    let mut on_data = |d: &DataMessage| {
        if too_many.get() {
            return;
        }
        let full = add_data(&mut out.borrow_mut(), d, &last_stamp);
        too_many.set(full);
    };
    let mut on_param = |p: &ParameterMessage| {
        add_param(&mut out.borrow_mut(), p, last_stamp.get());
    };
    let mut on_info = |i: &InfoMessage| {
        if i.key == "ver_sw_release" && i.type_str == "uint32_t" && i.value.len() >= 4 {
            out.borrow_mut().release = Some(u32::from_le_bytes(
                i.value[..4].try_into().expect("4 bytes"),
            ));
        }
    };
    let ending = {
        let mut parser = LogParser::default();
        parser.set_data_message_callback(&mut on_data);
        parser.set_parameter_message_callback(&mut on_param);
        parser.set_info_message_callback(&mut on_info);
        feed_ulog(path, &mut parser, &|| too_many.get())?
    };
    if too_many.get() {
        return Err(FileError::new(
            path,
            "",
            format!("more than {MAX_ROWS} rows of the estimator topics"),
        ));
    }
    Ok((out.into_inner(), ending))
}

/// Keep what the report uses of a data message: an aiding source's rate, an estimator
/// topic's fields; note the latest timestamp in `last_stamp`. `true` once the rows kept
/// pass [`MAX_ROWS`].
fn add_data(out: &mut Read, d: &DataMessage, last_stamp: &Cell<u64>) -> bool {
    let f = d.flattened_format;
    let name = f.message_name();
    let data = d.data;
    let read_u64 = |field: &str| -> Option<u64> {
        let x = f.field_iter().find(|x| x.flattened_field_name == field)?;
        let o = x.offset as usize;
        data.get(o..o + 8)
            .map(|b| u64::from_le_bytes(b.try_into().expect("8 bytes")))
    };
    let stamp = read_u64("timestamp");
    if let Some(s) = stamp {
        last_stamp.set(last_stamp.get().max(s));
    }
    if SOURCE_TOPICS.contains(&name) {
        if let Some(s) = stamp {
            let e = out.sources.entry(name.to_string()).or_insert((0, s, s));
            e.0 += 1;
            e.1 = e.1.min(s);
            e.2 = e.2.max(s);
        }
        return false;
    }
    let Some(keep) = keeps(name) else {
        return false;
    };
    // `rows` counts the innovation rows (what the summary reports); the cap every kept row.
    if matches!(name, INNOVATIONS | VARIANCES | LEGACY) || name.starts_with(AID_SRC) {
        out.rows += 1;
    }
    out.kept += 1;
    if out.kept > MAX_ROWS {
        return true;
    }
    let fields: Vec<_> = f
        .field_iter()
        .filter(|x| keep(&x.flattened_field_name, &x.field_type))
        .collect();
    let sample = read_u64("timestamp_sample");
    let Some(stamp) = stamp else {
        return false;
    };
    let topic = out
        .topics
        .entry((name.to_string(), d.multi_id.value()))
        .or_default();
    if topic.names.is_empty() && topic.times.is_empty() {
        topic.names = fields
            .iter()
            .map(|x| x.flattened_field_name.clone())
            .collect();
        topic.sampled_time = sample.is_some();
    }
    if fields.len() != topic.names.len() {
        return false;
    }
    topic.times.push(sample.unwrap_or(stamp));
    topic.stamps.push(stamp);
    topic.values.push(
        fields
            .iter()
            .map(|x| value_at(data, x.offset, &x.field_type))
            .collect(),
    );
    false
}

/// Keep an estimator parameter: its value in the definitions, or its change at
/// `last_stamp` during the data.
fn add_param(out: &mut Read, p: &ParameterMessage, last_stamp: u64) {
    let (name, value, stage) = match p {
        ParameterMessage::Float(n, v, s) => (*n, f64::from(*v), s),
        ParameterMessage::Int32(n, v, s) => (*n, f64::from(*v), s),
    };
    if !estimator_param(name) {
        return;
    }
    match stage {
        LogStage::Definitions => {
            out.params.insert(name.to_string(), value);
        }
        LogStage::Data => {
            out.param_changes
                .push((last_stamp, name.to_string(), value));
        }
    }
}

/// The 7 bytes every ULog file starts with (then a version byte and a 64-bit timestamp).
const MAGIC: [u8; 7] = [b'U', b'L', b'o', b'g', 0x01, 0x12, 0x35];

/// Refuse a file that does not start with the ULog header before the parser sees it (a
/// short file would otherwise read as a truncated log); the header's timestamp, µs.
fn check_magic(path: &Path) -> Result<u64, FileError> {
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
    Ok(u64::from_le_bytes(head[8..16].try_into().expect("8 bytes")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rate_counts_the_intervals_between_the_events_not_the_events() {
        // Eleven rows 0.1 s apart span 1 s: 10 Hz (11 would count a fence's posts).
        assert_eq!(per_second(11, 1.0), Some(10.0));
        assert_eq!(per_second(2, 0.25), Some(4.0));
        assert_eq!(per_second(1, 1.0), None);
        assert_eq!(per_second(0, 1.0), None);
        assert_eq!(per_second(5, 0.0), None);
        let topic = Topic {
            stamps: (0..=20).map(|k| 1_000_000 + 50_000 * k).collect(),
            ..Topic::default()
        };
        assert_eq!(topic.rate_hz(), 20.0);
        assert_eq!(Topic::default().rate_hz(), 0.0);
    }
}

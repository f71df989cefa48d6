//! Knowing the estimator: who published the innovations, which aiding sources EKF2 was
//! fusing at each time (`estimator_status_flags`, or `control_mode_flags` of
//! `estimator_status` in releases before v1.13), and which source each channel belongs to.

use std::collections::BTreeMap;

use super::read::{EKF2_TIMESTAMPS, Read, STATUS, STATUS_FLAGS, Topic, per_second};

/// The control-status flags EKF2 reports, by their bit in `control_mode_flags` (the names
/// of `estimator_status_flags`' `cs_*` fields, which follow the same order and go on past
/// bit 31).
const FLAGS: [&str; 39] = [
    "tilt_align",
    "yaw_align",
    "gps",
    "opt_flow",
    "mag_hdg",
    "mag_3d",
    "mag_dec",
    "in_air",
    "wind",
    "baro_hgt",
    "rng_hgt",
    "gps_hgt",
    "ev_pos",
    "ev_yaw",
    "ev_hgt",
    "fuse_beta",
    "mag_field_disturbed",
    "fixed_wing",
    "mag_fault",
    "fuse_aspd",
    "gnd_effect",
    "rng_stuck",
    "gps_yaw",
    "mag_aligned_in_flight",
    "ev_vel",
    "synthetic_mag_z",
    "vehicle_at_rest",
    "gps_yaw_fault",
    "rng_fault",
    "inertial_dead_reckoning",
    "wind_dead_reckoning",
    "rng_kin_consistent",
    "fake_pos",
    "fake_hgt",
    "gravity_vector",
    "mag",
    "ev_yaw_fault",
    "mag_heading_consistent",
    "aux_gpos",
];

fn bit(name: &str) -> Option<u64> {
    FLAGS.iter().position(|f| *f == name).map(|i| 1u64 << i)
}

/// Whether flag `name` is set in `flags` (bits of [`FLAGS`]).
pub(super) fn has(flags: u64, name: &str) -> bool {
    bit(name).is_some_and(|b| flags & b != 0)
}

/// One instance's control-status flags over time.
#[derive(Debug, Default)]
pub(super) struct Flags {
    /// (time µs, flags as bits of [`FLAGS`]), in time order.
    rows: Vec<(u64, u64)>,
    /// The log names the fake-position / fake-height states itself (v1.14+).
    pub has_fake: bool,
}

impl Flags {
    /// The flags of instance `inst`, from `estimator_status_flags` or else
    /// `estimator_status.control_mode_flags`; None when the log has neither.
    pub fn of(read: &Read, inst: u8) -> Option<Flags> {
        if let Some(t) = read.topics.get(&(STATUS_FLAGS.to_string(), inst))
            && !t.times.is_empty()
        {
            let cols: Vec<(usize, u64)> = t
                .names
                .iter()
                .enumerate()
                .filter_map(|(i, n)| n.strip_prefix("cs_").and_then(bit).map(|b| (i, b)))
                .collect();
            let has_fake = t.names.iter().any(|n| n == "cs_fake_pos");
            return Some(Flags {
                rows: rows_of(t, |v| {
                    cols.iter()
                        .filter(|(i, _)| v[*i] != 0.0)
                        .fold(0, |acc, (_, b)| acc | b)
                }),
                has_fake,
            });
        }
        let t = read.topics.get(&(STATUS.to_string(), inst))?;
        let c = t.column("control_mode_flags")?;
        if t.times.is_empty() {
            return None;
        }
        Some(Flags {
            rows: rows_of(t, |v| (v[c].max(0.0) as u64) & 0xFFFF_FFFF),
            has_fake: false,
        })
    }

    /// The flags in force at `t` (µs): the latest row at or before it; None before the first.
    pub fn at(&self, t: u64) -> Option<u64> {
        let i = self.rows.partition_point(|r| r.0 <= t);
        (i > 0).then(|| self.rows[i - 1].1)
    }

    /// Seconds a channel of `source` was active from the first status row to `end` (µs).
    pub fn active_seconds(&self, source: &Source, end: u64) -> f64 {
        let mut total = 0.0;
        for (k, &(t, f)) in self.rows.iter().enumerate() {
            let next = self.rows.get(k + 1).map_or(end, |r| r.0).min(end);
            if next > t && judged_under(source, Some(f), self.has_fake) == Status::Active {
                total += (next - t) as f64 * 1e-6;
            }
        }
        total
    }

    /// When each flag of `mask` turns on or off: (time µs, flag name, on).
    pub fn changes(&self, mask: u64) -> Vec<(u64, &'static str, bool)> {
        let mut out = Vec::new();
        let mut prev: Option<u64> = None;
        for &(t, f) in &self.rows {
            let before = prev.unwrap_or(0);
            let changed = (f ^ before) & mask;
            for (i, name) in FLAGS.iter().enumerate() {
                if changed & (1 << i) != 0 && (prev.is_some() || f & (1 << i) != 0) {
                    out.push((t, *name, f & (1 << i) != 0));
                }
            }
            prev = Some(f);
        }
        out
    }
}

fn rows_of(t: &Topic, flags: impl Fn(&[f64]) -> u64) -> Vec<(u64, u64)> {
    // The status is published when it changes, not at the filter's rate; its rows are in
    // file order, which the logger keeps in time order per topic, but sort to be sure.
    let mut rows: Vec<(u64, u64)> = t
        .stamps
        .iter()
        .zip(&t.values)
        .map(|(&s, v)| (s, flags(v)))
        .collect();
    rows.sort_by_key(|r| r.0);
    rows
}

/// The flags that say an aiding source is fused, for the report's event markers.
pub(super) fn aiding_mask() -> u64 {
    [
        "gps",
        "opt_flow",
        "mag_hdg",
        "mag_3d",
        "baro_hgt",
        "rng_hgt",
        "gps_hgt",
        "ev_pos",
        "ev_yaw",
        "ev_hgt",
        "fuse_beta",
        "fuse_aspd",
        "gps_yaw",
        "ev_vel",
        "fake_pos",
        "fake_hgt",
        "gravity_vector",
        "aux_gpos",
    ]
    .iter()
    .filter_map(|n| bit(n))
    .fold(0, |a, b| a | b)
}

/// A flag's name in words for the report.
pub(super) fn flag_words(name: &str) -> &'static str {
    match name {
        "gps" => "GPS",
        "opt_flow" => "optical flow",
        "mag_hdg" => "magnetic heading",
        "mag_3d" | "mag" => "3-axis magnetometer",
        "baro_hgt" => "baro height",
        "rng_hgt" => "range-finder height",
        "gps_hgt" => "GPS height",
        "ev_pos" => "vision position",
        "ev_yaw" => "vision yaw",
        "ev_hgt" => "vision height",
        "ev_vel" => "vision velocity",
        "fuse_beta" => "synthetic sideslip",
        "fuse_aspd" => "airspeed",
        "gps_yaw" => "GNSS yaw",
        "fake_pos" => "fake position",
        "fake_hgt" => "fake height",
        "gravity_vector" => "gravity vector",
        "aux_gpos" => "auxiliary global position",
        _ => "other",
    }
}

/// What a channel of the innovation topics measures, and when it counts as fused.
#[derive(Debug, Clone, PartialEq)]
pub(super) enum Source {
    /// A sensor fused while one of the flags is set; its words.
    Sensor {
        flags: Vec<&'static str>,
        words: &'static str,
    },
    /// Horizontal position: GPS, vision, or — with no horizontal aiding — fake position.
    HorizontalPosition {
        flags: Vec<&'static str>,
        words: &'static str,
    },
    /// A channel no flag tells about (drag, auxiliary velocity, terrain): judged whenever
    /// it updates.
    Always(&'static str),
}

/// The source of channel `base` (the name without its index) of the estimator_innovations
/// layout, or of the legacy `ekf2_innovations` one (`vel_pos` component `idx`).
pub(super) fn source_of(base: &str, idx: Option<usize>) -> Source {
    use Source::*;
    match (base, idx) {
        ("gps_hvel" | "gps_vvel", _) => Sensor {
            flags: vec!["gps"],
            words: "GPS velocity",
        },
        ("gps_hpos", _) => HorizontalPosition {
            flags: vec!["gps"],
            words: "GPS horizontal position",
        },
        ("gps_vpos", _) => Sensor {
            flags: vec!["gps_hgt"],
            words: "GPS height",
        },
        ("baro_vpos", _) => Sensor {
            flags: vec!["baro_hgt"],
            words: "baro height",
        },
        ("rng_vpos", _) => Sensor {
            flags: vec!["rng_hgt"],
            words: "range-finder height",
        },
        ("ev_hvel" | "ev_vvel", _) => Sensor {
            flags: vec!["ev_vel"],
            words: "vision velocity",
        },
        ("ev_hpos", _) => HorizontalPosition {
            flags: vec!["ev_pos"],
            words: "vision position",
        },
        ("ev_vpos", _) => Sensor {
            flags: vec!["ev_hgt"],
            words: "vision height",
        },
        ("flow", _) => Sensor {
            flags: vec!["opt_flow"],
            words: "optical flow",
        },
        ("heading", _) => Sensor {
            flags: vec!["mag_hdg", "ev_yaw", "gps_yaw"],
            words: "heading",
        },
        ("mag_field" | "mag", _) => Sensor {
            flags: vec!["mag_3d", "mag"],
            words: "3-axis magnetometer",
        },
        ("airspeed", _) => Sensor {
            flags: vec!["fuse_aspd"],
            words: "airspeed",
        },
        ("beta", _) => Sensor {
            flags: vec!["fuse_beta"],
            words: "synthetic sideslip",
        },
        ("gravity", _) => Sensor {
            flags: vec!["gravity_vector"],
            words: "gravity vector",
        },
        // The legacy layout: velocity N, E, D then position N, E, D.
        ("vel_pos", Some(0..=2)) => Sensor {
            flags: vec!["gps", "ev_vel"],
            words: "velocity (GPS or vision)",
        },
        ("vel_pos", Some(3..=4)) => HorizontalPosition {
            flags: vec!["gps", "ev_pos"],
            words: "horizontal position (GPS or vision)",
        },
        ("vel_pos", Some(_)) => Sensor {
            flags: vec!["baro_hgt", "gps_hgt", "rng_hgt", "ev_hgt"],
            words: "height",
        },
        ("drag", _) => Always("multirotor drag"),
        ("aux_hvel" | "aux_vvel", _) => Always("auxiliary velocity"),
        ("hagl" | "hagl_rate" | "terr_flow", _) => Always("terrain estimator"),
        _ => Always("unknown source"),
    }
}

/// Whether a channel of `source` counts as fused by its own source under `flags` (None: the
/// log has no flags), and whether it is fake-position fusion.
pub(super) fn judged_under(source: &Source, flags: Option<u64>, has_fake: bool) -> Status {
    let any = |names: &[&str], f: u64| names.iter().any(|n| bit(n).is_some_and(|b| f & b != 0));
    match (source, flags) {
        (Source::Always(_), _) => Status::Active,
        (_, None) => Status::Unknown,
        (Source::Sensor { flags: names, .. }, Some(f)) => {
            if any(names, f) {
                Status::Active
            } else {
                Status::Inactive
            }
        }
        (Source::HorizontalPosition { flags: names, .. }, Some(f)) => {
            if any(names, f) {
                Status::Active
            } else if (has_fake && any(&["fake_pos"], f))
                || (!has_fake && !any(&["gps", "opt_flow", "ev_pos", "ev_vel", "aux_gpos"], f))
            {
                // With no horizontal aiding EKF2 fuses a fake position to bound the drift:
                // its innovations are the filter's, not a sensor's.
                Status::Fake
            } else {
                Status::Inactive
            }
        }
    }
}

/// A channel's state at one time.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Status {
    Active,
    Inactive,
    Fake,
    /// Before the first status row, or no status in the log.
    Unknown,
}

/// A log whose innovations another estimator than EKF2 published: the parameter that says
/// so, its value, and the estimator it selects.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error(
    "{param} = {value}: the innovations were published by {who}, not EKF2; its \"variances\" are not EKF2's innovation variances S, so ν²/S is not a NIS"
)]
pub(super) struct NotEkf2 {
    param: &'static str,
    value: f64,
    who: &'static str,
}

/// Who published the innovation topics, and how that is known: Ok((name, evidence)) for
/// EKF2, Err(reason) for anything else.
pub(super) fn publisher(read: &Read, legacy: bool) -> Result<(String, String), NotEkf2> {
    let group = ["SYS_MC_EST_GROUP", "SYS_EST_GROUP"]
        .iter()
        .find_map(|p| read.params.get(*p).map(|v| (*p, *v)));
    let ekf2_ran = read.topics.keys().any(|(n, _)| n == EKF2_TIMESTAMPS);
    if ekf2_ran {
        return Ok(("EKF2".into(), format!("the log has {EKF2_TIMESTAMPS}")));
    }
    match group {
        Some((p, 2.0)) => Ok(("EKF2".into(), format!("{p} = 2"))),
        Some((p, v)) => {
            let who = match v as i64 {
                0 => "INAV",
                1 => "LPE (local_position_estimator)",
                3 => "the Q attitude estimator",
                _ => "an estimator other than EKF2",
            };
            Err(NotEkf2 {
                param: p,
                value: v,
                who,
            })
        }
        None if legacy => Ok((
            "EKF2".into(),
            "assumed: the log has no SYS_MC_EST_GROUP and no ekf2_timestamps to confirm it".into(),
        )),
        None => Ok((
            "EKF2".into(),
            "only EKF2 publishes these topics (the log has no SYS_MC_EST_GROUP)".into(),
        )),
    }
}

/// `ver_sw_release` as `v1.11.3` (a release candidate or beta gets its type suffix).
pub(super) fn version(release: u32) -> String {
    let (major, minor, patch, kind) = (
        release >> 24,
        (release >> 16) & 0xFF,
        (release >> 8) & 0xFF,
        release & 0xFF,
    );
    let suffix = match kind {
        0..=63 => " (development)",
        64..=127 => " (alpha)",
        128..=191 => " (beta)",
        192..=254 => " (release candidate)",
        _ => "",
    };
    // A release build has type 255; a version with type 0 is a development build by the
    // format, but the logs PX4 itself ships use 0 for tagged releases too.
    let suffix = if kind == 0 { "" } else { suffix };
    format!("v{major}.{minor}.{patch}{suffix}")
}

/// The logged rate of each source's own data topic, rows per second, by flag-words.
pub(super) fn source_rates(read: &Read) -> BTreeMap<&'static str, f64> {
    let rate = |name: &str| {
        read.sources
            .get(name)
            .and_then(|&(n, a, b)| per_second(n, b.saturating_sub(a) as f64 * 1e-6))
    };
    let mut out = BTreeMap::new();
    for (words, topics) in [
        ("baro height", &["vehicle_air_data"][..]),
        ("GPS", &["vehicle_gps_position", "sensor_gps"][..]),
        ("magnetometer", &["vehicle_magnetometer"][..]),
        ("range finder", &["distance_sensor"][..]),
        (
            "optical flow",
            &["vehicle_optical_flow", "optical_flow"][..],
        ),
        ("vision", &["vehicle_visual_odometry"][..]),
        ("airspeed", &["airspeed", "airspeed_validated"][..]),
    ] {
        if let Some(r) = topics.iter().find_map(|t| rate(t)) {
            out.insert(words, r);
        }
    }
    out
}

/// The key of [`source_rates`] for a channel base name.
pub(super) fn rate_key(base: &str) -> Option<&'static str> {
    Some(match base {
        "baro_vpos" | "baro_hgt" => "baro height",
        "gps_hpos" | "gps_vpos" | "gps_hvel" | "gps_vvel" | "gnss_pos" | "gnss_vel"
        | "gnss_hgt" => "GPS",
        "mag_field" | "heading" | "mag" | "mag_heading" => "magnetometer",
        "rng_vpos" | "rng_hgt" | "hagl" => "range finder",
        "flow" | "optical_flow" => "optical flow",
        "ev_hpos" | "ev_vpos" | "ev_hvel" | "ev_vvel" | "ev_pos" | "ev_vel" | "ev_hgt" => "vision",
        "airspeed" => "airspeed",
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn releases_read_as_versions() {
        assert_eq!(version(0x010B_0300), "v1.11.3");
        assert_eq!(version(0x010F_00FF), "v1.15.0");
        assert_eq!(version(0x010D_00C1), "v1.13.0 (release candidate)");
    }

    #[test]
    fn fake_position_is_told_apart_from_gps() {
        let src = source_of("gps_hpos", Some(0));
        let f = |names: &[&str]| names.iter().filter_map(|n| bit(n)).fold(0, |a, b| a | b);
        assert_eq!(
            judged_under(&src, Some(f(&["gps", "baro_hgt"])), false),
            Status::Active
        );
        assert_eq!(
            judged_under(&src, Some(f(&["baro_hgt", "mag_hdg"])), false),
            Status::Fake
        );
        // With the log's own fake-position flag, only that flag says fake.
        assert_eq!(
            judged_under(&src, Some(f(&["baro_hgt"])), true),
            Status::Inactive
        );
        assert_eq!(
            judged_under(&src, Some(f(&["fake_pos"])), true),
            Status::Fake
        );
        assert_eq!(judged_under(&src, None, false), Status::Unknown);
        let baro = source_of("baro_vpos", None);
        assert_eq!(
            judged_under(&baro, Some(f(&["gps"])), false),
            Status::Inactive
        );
    }
}

//! EKF2's own words: which parameter sets each channel's measurement noise, and what value
//! the log's innovations suggest for it.
//!
//! EKF2 takes each measurement's noise as a standard deviation parameter (`EKF2_BARO_NOISE`
//! in metres, ...) and fuses with `R = σ²` (after some internal changes: a GNSS receiver's
//! reported accuracy replaces `EKF2_GPS_P_NOISE` when it is worse, the range finder's noise
//! grows with distance, baro noise is inflated in ground effect). The innovation variance is
//! `S = H P H' + R`. When the innovations say S should be `r` times larger (r = gated NIS
//! average / its target) and the fault is R's, the `R` that gives it is `R + (r − 1) S̄` —
//! the part `H P H'` stays. The suggested σ is the parameter scaled by `√(R_new / R)`, with R
//! the mean observation variance the EKF logged (aid-source topics) or else the parameter
//! squared. When `R + (r − 1) S̄ ≤ 0`, no R gives the change: the suggestion is withheld.

use std::collections::BTreeMap;

use serde::Serialize;

use super::estimator::{self, Source};

/// A parameter to change, with the log's value and the suggested one.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ParamAdvice {
    /// The parameter, e.g. `EKF2_BARO_NOISE`.
    pub param: String,
    /// Its unit, e.g. `m`.
    pub unit: String,
    /// The value the log recorded (None: the log has no parameter section for it).
    pub value: Option<f64>,
    /// The suggested value (None when the evidence gives a direction but no size).
    pub suggested: Option<f64>,
    /// One line: `EKF2_BARO_NOISE = 3.5 m → about 2.4 m`, with the direction when no value.
    pub text: String,
}

/// The measurement-noise parameter of a channel (the name after `ekfN.`), and its unit.
/// `fused` says which aiding source was fused while the channel updated (see
/// [`fused_source`]: `baro`, `gps`, `rng`, `ev`, `gnss`), for the channels several sources
/// share: heading (magnetometer, vision or GNSS yaw) and the legacy `vel_pos` (velocity and
/// position from GPS or vision, height from baro, GPS, range finder or vision), which has
/// no parameter when the source is not known.
pub fn noise_param(channel: &str, fused: Option<&str>) -> Option<(&'static str, &'static str)> {
    let base = channel.split('[').next().unwrap_or(channel);
    let idx: Option<usize> = channel
        .split_once('[')
        .and_then(|(_, i)| i.trim_end_matches(']').parse().ok());
    Some(match base {
        "gps_hpos" | "gps_vpos" | "gnss_pos" | "gnss_hgt" => ("EKF2_GPS_P_NOISE", "m"),
        "gps_hvel" | "gps_vvel" | "gnss_vel" => ("EKF2_GPS_V_NOISE", "m/s"),
        "baro_vpos" | "baro_hgt" => ("EKF2_BARO_NOISE", "m"),
        "rng_vpos" | "rng_hgt" | "hagl" | "terrain_range_finder" => ("EKF2_RNG_NOISE", "m"),
        "ev_hpos" | "ev_vpos" | "ev_pos" | "ev_hgt" => ("EKF2_EVP_NOISE", "m"),
        "ev_hvel" | "ev_vvel" | "ev_vel" => ("EKF2_EVV_NOISE", "m/s"),
        "ev_yaw" => ("EKF2_EVA_NOISE", "rad"),
        "mag_field" | "mag" => ("EKF2_MAG_NOISE", "gauss"),
        "heading" | "mag_heading" => match fused {
            Some("ev") => ("EKF2_EVA_NOISE", "rad"),
            Some("gnss") => return None,
            _ => ("EKF2_HEAD_NOISE", "rad"),
        },
        "vel_pos" => match (idx?, fused?) {
            (0..=2, "gps") => ("EKF2_GPS_V_NOISE", "m/s"),
            (0..=2, "ev") => ("EKF2_EVV_NOISE", "m/s"),
            (3..=5, "gps") => ("EKF2_GPS_P_NOISE", "m"),
            (3..=5, "ev") => ("EKF2_EVP_NOISE", "m"),
            (5, "baro") => ("EKF2_BARO_NOISE", "m"),
            (5, "rng") => ("EKF2_RNG_NOISE", "m"),
            _ => return None,
        },
        "airspeed" => ("EKF2_EAS_NOISE", "m/s"),
        "beta" | "sideslip" => ("EKF2_BETA_NOISE", "rad"),
        "drag" => ("EKF2_DRAG_NOISE", "m/s²"),
        "gravity" => ("EKF2_GRAV_NOISE", "g"),
        "flow" | "optical_flow" => ("EKF2_OF_N_MIN", "rad/s"),
        _ => return None,
    })
}

/// The flags that fuse a shared channel's candidate sources, and each one's key for
/// [`noise_param`].
const SOURCE_KEYS: [(&str, &str); 10] = [
    ("baro_hgt", "baro"),
    ("gps_hgt", "gps"),
    ("rng_hgt", "rng"),
    ("ev_hgt", "ev"),
    ("gps", "gps"),
    ("ev_vel", "ev"),
    ("ev_pos", "ev"),
    ("mag_hdg", "mag"),
    ("ev_yaw", "ev"),
    ("gps_yaw", "gnss"),
];

/// Which of a channel's sources was fused (a key of [`SOURCE_KEYS`]): the one candidate flag
/// set on every judged update (`all`: the flags set on all of them), or else, for a height
/// channel, the primary height source `EKF2_HGT_MODE` names (0 baro, 1 GPS, 2 range finder,
/// 3 vision); None when neither says.
pub(super) fn fused_source(
    source: &Source,
    all: Option<u64>,
    params: &BTreeMap<String, f64>,
) -> Option<&'static str> {
    let candidates = match source {
        Source::Sensor { flags, .. } | Source::HorizontalPosition { flags, .. } => flags,
        Source::Always(_) => return None,
    };
    let keys: Vec<&str> = SOURCE_KEYS
        .iter()
        .filter(|(flag, _)| candidates.contains(flag))
        .filter(|(flag, _)| all.is_some_and(|f| estimator::has(f, flag)))
        .map(|(_, key)| *key)
        .collect();
    match keys.as_slice() {
        [one] => return Some(one),
        [first, rest @ ..] if rest.iter().all(|k| k == first) => return Some(first),
        _ => {}
    }
    if !candidates.contains(&"baro_hgt") {
        return None;
    }
    match params.get("EKF2_HGT_MODE").map(|v| *v as i64) {
        Some(0) => Some("baro"),
        Some(1) => Some("gps"),
        Some(2) => Some("rng"),
        Some(3) => Some("ev"),
        _ => None,
    }
}

/// The process-noise parameters every channel of an estimator shares, with units.
pub const PROCESS_NOISE: [(&str, &str); 2] =
    [("EKF2_ACC_NOISE", "m/s²"), ("EKF2_GYR_NOISE", "rad/s")];

/// The σ that makes `S` about `ratio` times larger for a channel whose noise parameter is
/// `sigma`, with mean innovation variance `mean_s` and mean observation variance `mean_r`
/// (None: `sigma²`). None when no positive R gives it.
pub fn suggested_sigma(sigma: f64, ratio: f64, mean_s: f64, mean_r: Option<f64>) -> Option<f64> {
    let r = mean_r.unwrap_or(sigma * sigma);
    if !(sigma > 0.0 && r > 0.0 && ratio.is_finite() && mean_s.is_finite()) {
        return None;
    }
    let r_new = r + (ratio - 1.0) * mean_s;
    (r_new > 0.0).then(|| sigma * (r_new / r).sqrt())
}

/// A value in 3 significant digits for the advice text.
pub(crate) fn sig3(v: f64) -> String {
    if v == 0.0 || !v.is_finite() {
        return format!("{v}");
    }
    let digits = (2 - v.abs().log10().floor() as i32).clamp(0, 8) as usize;
    format!("{v:.digits$}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_suggested_sigma_keeps_the_state_part_of_s() {
        // S = HPH' + R = 1 + 4; the innovations say S is 3 too large (ratio 0.4): R = 4 − 3.
        let s = suggested_sigma(2.0, 0.4, 5.0, None).unwrap();
        assert!((s - 1.0).abs() < 1e-12, "{s}");
        // An R that is all of S: σ scales by √ratio.
        let s = suggested_sigma(2.0, 0.25, 4.0, None).unwrap();
        assert!((s - 1.0).abs() < 1e-12, "{s}");
        // No positive R gives it.
        assert_eq!(suggested_sigma(2.0, 0.1, 10.0, None), None);
        // The logged R replaces σ² (EKF2 used the receiver's accuracy instead).
        let s = suggested_sigma(0.5, 2.0, 1.0, Some(1.0)).unwrap();
        assert!((s - 0.5 * 2f64.sqrt()).abs() < 1e-12, "{s}");
    }

    #[test]
    fn channels_map_to_their_parameters() {
        assert_eq!(
            noise_param("baro_vpos", None),
            Some(("EKF2_BARO_NOISE", "m"))
        );
        assert_eq!(
            noise_param("gps_hpos[1]", None),
            Some(("EKF2_GPS_P_NOISE", "m"))
        );
        assert_eq!(
            noise_param("heading", Some("ev")),
            Some(("EKF2_EVA_NOISE", "rad"))
        );
        assert_eq!(noise_param("aux_hvel[0]", None), None);
        // The legacy vel_pos has a parameter only once its source is known.
        assert_eq!(noise_param("vel_pos[5]", None), None);
        assert_eq!(
            noise_param("vel_pos[5]", Some("baro")),
            Some(("EKF2_BARO_NOISE", "m"))
        );
        assert_eq!(
            noise_param("vel_pos[4]", Some("gps")),
            Some(("EKF2_GPS_P_NOISE", "m"))
        );
        assert_eq!(sig3(2.4375), "2.44");
        assert_eq!(sig3(0.0123456), "0.0123");
    }
}

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

use serde::Serialize;

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
/// `active` says which aiding sources are fused while the channel updates, for the channels
/// several sources share (heading: magnetometer, external vision or GNSS yaw).
pub fn noise_param(
    channel: &str,
    heading_source: Option<&str>,
) -> Option<(&'static str, &'static str)> {
    let base = channel.split('[').next().unwrap_or(channel);
    Some(match base {
        "gps_hpos" | "gps_vpos" | "gnss_pos" | "gnss_hgt" => ("EKF2_GPS_P_NOISE", "m"),
        "gps_hvel" | "gps_vvel" | "gnss_vel" => ("EKF2_GPS_V_NOISE", "m/s"),
        "baro_vpos" | "baro_hgt" => ("EKF2_BARO_NOISE", "m"),
        "rng_vpos" | "rng_hgt" | "hagl" | "terrain_range_finder" => ("EKF2_RNG_NOISE", "m"),
        "ev_hpos" | "ev_vpos" | "ev_pos" | "ev_hgt" => ("EKF2_EVP_NOISE", "m"),
        "ev_hvel" | "ev_vvel" | "ev_vel" => ("EKF2_EVV_NOISE", "m/s"),
        "ev_yaw" => ("EKF2_EVA_NOISE", "rad"),
        "mag_field" | "mag" => ("EKF2_MAG_NOISE", "gauss"),
        "heading" | "mag_heading" => match heading_source {
            Some("ev") => ("EKF2_EVA_NOISE", "rad"),
            Some("gnss") => return None,
            _ => ("EKF2_HEAD_NOISE", "rad"),
        },
        "airspeed" => ("EKF2_EAS_NOISE", "m/s"),
        "beta" | "sideslip" => ("EKF2_BETA_NOISE", "rad"),
        "drag" => ("EKF2_DRAG_NOISE", "m/s²"),
        "gravity" => ("EKF2_GRAV_NOISE", "g"),
        "flow" | "optical_flow" => ("EKF2_OF_N_MIN", "rad/s"),
        _ => return None,
    })
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
        assert_eq!(sig3(2.4375), "2.44");
        assert_eq!(sig3(0.0123456), "0.0123");
    }
}

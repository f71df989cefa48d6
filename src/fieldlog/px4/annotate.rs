//! After the statistics: what each PX4 channel's EKF said beside its innovations, and the
//! finding of a failing channel put in EKF2's parameters with the log's values.

use super::ekf2::{self, PROCESS_NOISE, ParamAdvice, sig3};
use super::info::Px4Info;
use crate::fieldlog::report::{NisReport, SensorReport};
use crate::stats::Suspect;

/// Why a suggested value is only a first step, per parameter, where EKF2 changes the noise
/// it is given before it fuses (None: it uses the parameter as is).
fn caveat(param: &str) -> &'static str {
    match param {
        "EKF2_GPS_P_NOISE" | "EKF2_GPS_V_NOISE" => {
            "EKF2 uses the receiver's reported accuracy instead where that is worse"
        }
        "EKF2_BARO_NOISE" => "EKF2 inflates baro noise in ground effect",
        "EKF2_RNG_NOISE" => "EKF2 grows range noise with distance (EKF2_RNG_SFE)",
        "EKF2_EVP_NOISE" | "EKF2_EVV_NOISE" | "EKF2_EVA_NOISE" => {
            "EKF2 uses the vision message's own variance unless EKF2_EV_NOISE_MD says otherwise"
        }
        "EKF2_OF_N_MIN" => {
            "EKF2 scales flow noise with the sensor's quality between EKF2_OF_N_MIN and EKF2_OF_N_MAX"
        }
        _ => "EKF2 may change the variance it is given before fusing",
    }
}

/// Advice on parameter `p` (in `unit`) with the log's value and a direction, no size.
fn direction_only(info: &Px4Info, p: &str, unit: &str, dir: &str) -> ParamAdvice {
    let value = info.params.get(p).copied();
    let now = value.map_or("not in the log".to_string(), |v| {
        format!("{} {unit}", sig3(v))
    });
    ParamAdvice {
        param: p.to_string(),
        unit: unit.to_string(),
        value,
        suggested: None,
        text: format!("{dir} {p} (now {now})"),
    }
}

/// The parameter advice for sensor `s` of a log with `info`.
fn advise(s: &SensorReport, info: &Px4Info) -> Vec<ParamAdvice> {
    let Some(finding) = &s.finding else {
        return Vec::new();
    };
    let Some(ch) = &s.px4 else {
        return Vec::new();
    };
    let ratio = s.nis.mean / s.nis.target;
    match finding.suspect {
        Some(Suspect::R) => {
            let Some(param) = ch.noise_param.clone() else {
                return Vec::new();
            };
            let unit = ch.unit.clone().unwrap_or_default();
            let value = info.params.get(&param).copied();
            let dir = if ratio > 1.0 { "increase" } else { "decrease" };
            let suggested =
                value.and_then(|v| ekf2::suggested_sigma(v, ratio, ch.mean_s, ch.mean_r));
            let text = match (value, suggested) {
                (Some(v), Some(x)) => {
                    let mut t = format!("{param} = {} {unit} → about {} {unit}", sig3(v), sig3(x));
                    if ch.mean_r.is_none() {
                        t.push_str(&format!(" ({})", caveat(&param)));
                    }
                    t
                }
                (Some(v), None) => format!(
                    "{dir} {param} (now {} {unit}); no value of it alone gives the S the innovations ask for: its share of S is smaller than the change, so Q is in it too",
                    sig3(v)
                ),
                (None, _) => format!("{dir} {param} (the log does not record its value)"),
            };
            vec![ParamAdvice {
                param,
                unit,
                value,
                suggested,
                text,
            }]
        }
        Some(Suspect::Q) => {
            let dir = if ratio > 1.0 { "increase" } else { "decrease" };
            PROCESS_NOISE
                .iter()
                .map(|(p, unit)| direction_only(info, p, unit, dir))
                .collect()
        }
        Some(Suspect::QAndR) => {
            // Q and R together: every parameter that sets this S, by name and value, with
            // no size (the NIS cannot split the change between them).
            let dir = if ratio > 1.0 { "increase" } else { "decrease" };
            let own = ch
                .noise_param
                .as_deref()
                .map(|p| (p, ch.unit.as_deref().unwrap_or("")));
            own.into_iter()
                .chain(PROCESS_NOISE.iter().copied())
                .map(|(p, unit)| direction_only(info, p, unit, dir))
                .collect()
        }
        _ => Vec::new(),
    }
}

/// Attach each PX4 channel's EKF view to its sensor, and give a finding on R or Q its EKF2
/// parameters.
pub(in crate::fieldlog) fn annotate(report: &mut NisReport) {
    let warnings: Vec<String> = report
        .sources
        .iter()
        .filter_map(|s| s.px4.as_ref())
        .flat_map(|p| p.warnings.iter().cloned())
        .collect();
    report.warnings.extend(warnings);
    let infos: Vec<&Px4Info> = report
        .sources
        .iter()
        .filter_map(|s| s.px4.as_ref())
        .collect();
    if infos.is_empty() {
        return;
    }
    let mut advice = Vec::new();
    for (k, s) in report.sensors.iter_mut().enumerate() {
        let Some((info, ch)) = infos.iter().find_map(|i| {
            i.channels
                .iter()
                .find(|c| c.name == s.name)
                .map(|c| (*i, c))
        }) else {
            continue;
        };
        s.px4 = Some(ch.clone());
        advice.push((k, advise(s, info)));
    }
    for (k, params) in advice {
        let s = &mut report.sensors[k];
        if let (Some(f), false) = (&mut s.finding, params.is_empty()) {
            let words: Vec<&str> = params.iter().map(|p| p.text.as_str()).collect();
            f.action = format!("{}: {}", f.action, words.join("; "));
            if params
                .iter()
                .all(|p| p.suggested.is_none() && p.value.is_some())
                && matches!(f.suspect, Some(Suspect::Q | Suspect::QAndR))
            {
                // The NIS gives the direction of Q, not its size (that needs the states).
                f.action.push_str(", in steps, judging each next log");
            }
        }
        s.parameters = params;
    }
}

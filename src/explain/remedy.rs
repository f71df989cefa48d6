//! What a fitted hypothesis says, and what to change: read off the values its trial fit.

use super::explanation::Trial;
use crate::experiment::{Changed, Hypothesis};

/// A value in a few significant digits.
pub(super) fn fmt_value(v: f64) -> String {
    if v.abs() >= 100.0 || (v != 0.0 && v.abs() < 0.01) {
        format!("{v:.3e}")
    } else {
        format!("{v:.3}")
    }
}

/// A value in a few significant digits and its unit, if it has one.
pub(super) fn with_unit(v: f64, unit: &str) -> String {
    if unit.is_empty() {
        fmt_value(v)
    } else {
        format!("{} {unit}", fmt_value(v))
    }
}

/// The added parameters of `h` whose fitted values change something, as `name value`.
fn moved(h: &dyn Changed, t: &Trial) -> Vec<(String, f64)> {
    h.added()
        .iter()
        .filter(|a| a.effect)
        .filter_map(|a| {
            let v = t.value(&a.def.name)?;
            (!a.is_neutral(v)).then(|| (a.def.name.clone(), v))
        })
        .collect()
}

/// The components a per-component change moved (`gain_x` → `x`), or all of them.
fn components(h: &dyn Changed, t: &Trial, prefix: &str) -> Vec<String> {
    moved(h, t)
        .iter()
        .filter_map(|(n, _)| n.strip_prefix(prefix).map(str::to_string))
        .collect()
}

/// `place`, and the components where the change is, where there are any.
fn subject(place: &str, z: &[String]) -> String {
    if z.is_empty() {
        place.to_string()
    } else {
        format!("{place}: {}", z.join(", "))
    }
}

/// The subject (where the change is), what the fit says, and the remedy.
pub(super) fn read(h: &dyn Changed, t: &Trial) -> (String, String, String) {
    let place = h.hypothesis().place();
    let fitted: Vec<String> = h
        .added()
        .iter()
        .filter_map(|a| {
            t.value(&a.def.name).map(|v| {
                let (name, v) = h.reading(&a.def.name, v);
                format!("{name} = {}", fmt_value(v))
            })
        })
        .collect();
    let says = if fitted.is_empty() {
        String::new()
    } else {
        format!("fitted {}", fitted.join(", "))
    };
    let v = |name: &str| t.value(name).unwrap_or(f64::NAN);
    let (subject, remedy) = match h.hypothesis() {
        Hypothesis::TimeStep => (
            format!("{place}: F and Q"),
            format!(
                "build F and Q for a step {} times the configured one (the data's sample period)",
                fmt_value(v("dt_scale"))
            ),
        ),
        Hypothesis::InitialCovariance => (
            format!("{place}: P0"),
            format!("scale the filter's P0 by {}", fmt_value(v("p0_scale"))),
        ),
        Hypothesis::SensorGain => {
            let z = components(h, t, "gain_");
            (
                subject(place, &z),
                format!(
                    "the readings of {} scale the state by the fitted gains: calibrate the scale factor, or put it in H",
                    z.join(", ")
                ),
            )
        }
        Hypothesis::MeasurementMatrix => {
            let z: Vec<String> = moved(h, t).into_iter().map(|(n, _)| n).collect();
            (
                format!("{place}: H"),
                format!(
                    "correct H by the fitted rotation and gains ({}): a misalignment between the components",
                    z.join(", ")
                ),
            )
        }
        Hypothesis::Delay(d) => (
            format!("{place}: every reading"),
            format!(
                "the readings describe the state {d} step{} back: model the delay (lagged states) or time-stamp them",
                if d == 1 { "" } else { "s" }
            ),
        ),
        Hypothesis::ColouredNoise => {
            let z = components(h, t, "gm_var_");
            (
                subject(place, &z),
                format!(
                    "the noise of {} is correlated in time: model it as a first-order Gauss–Markov state (the fitted correlation and variance)",
                    z.join(", ")
                ),
            )
        }
        Hypothesis::SensorBias => {
            let z: Vec<String> = moved(h, t)
                .iter()
                .filter_map(|(n, _)| {
                    n.strip_prefix("bias_mean_")
                        .or_else(|| n.strip_prefix("bias_var_"))
                        .map(str::to_string)
                })
                .fold(Vec::new(), |mut acc, c| {
                    if !acc.contains(&c) {
                        acc.push(c);
                    }
                    acc
                });
            let kinds: Vec<String> = z
                .iter()
                .map(|c| {
                    let mean_moved = moved(h, t).iter().any(|(n, _)| *n == format!("bias_mean_{c}"));
                    let var_moved = moved(h, t).iter().any(|(n, _)| *n == format!("bias_var_{c}"));
                    match (mean_moved, var_moved) {
                        (true, false) => format!("{c}: constant in every run"),
                        (false, true) => format!("{c}: drawn anew in every run"),
                        _ => format!("{c}: a constant part and a part drawn per run"),
                    }
                })
                .collect();
            (
                subject(place, &z),
                format!(
                    "model the bias ({}) with a bias state, or calibrate it out",
                    kinds.join("; ")
                ),
            )
        }
        Hypothesis::MotionState => {
            let q = components(h, t, "singer_drive_");
            (
                if q.is_empty() {
                    place.to_string()
                } else {
                    format!("{place}: the input of {}", q.join(", "))
                },
                "add the state the truth has and the filter lacks: a Gauss–Markov (Singer) acceleration on that input, with the fitted rate and variance".to_string(),
            )
        }
        Hypothesis::NoiseKind => (
            format!("{place}: Q's kind"),
            "build Q as the other kind of white noise (continuous ↔ piecewise constant over the step)".to_string(),
        ),
        Hypothesis::FullR => {
            let z: Vec<String> = moved(h, t).into_iter().map(|(n, _)| n).collect();
            (
                format!("{place}: R"),
                format!(
                    "give R the correlations the fit found ({})",
                    z.join(", ")
                ),
            )
        }
    };
    (subject, says, remedy)
}

//! The PX4 part of the `autotune nis` report: who published the innovations, which
//! estimator instance was primary, what the EKF itself said about each channel (its test
//! ratios, gate and rejections beside the NIS), the channels left unjudged and why, the
//! EKF2 parameter advice and the log's events.

use std::fmt::Write;

use super::captions::{count, num};
use crate::fieldlog::{NisReport, Px4Channel, Px4Info, SensorReport};
use crate::report::html::escape;

/// Events listed inline; more are folded away.
const EVENTS_INLINE: usize = 12;

/// The instance number of a channel named `ekfN.…`.
fn instance_of(name: &str) -> Option<u8> {
    name.strip_prefix("ekf")?.split('.').next()?.parse().ok()
}

/// A number in few digits without trailing zeros ("5", "18.8", "61.5").
fn trimmed(v: f64) -> String {
    let n = num(v);
    if n.contains('.') && !n.contains('e') {
        n.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        n
    }
}

/// A rate in Hz ("5 Hz", "18.8 Hz").
fn hz(v: f64) -> String {
    format!("{} Hz", trimmed(v))
}

/// The fusion note of a channel whose updates are samples of its fusions: "samples of
/// fusions: logged at 5 Hz, source at 18.8 Hz". The logged rate is the instance's topic
/// rate when the log says it, else the channel's own update rate.
pub(super) fn fusion_note(info: Option<&Px4Info>, name: &str, c: &Px4Channel) -> Option<String> {
    if !c.sampled {
        return None;
    }
    let logged = info
        .zip(instance_of(name))
        .and_then(|(info, k)| info.instances.iter().find(|i| i.index == k))
        .map_or(c.update_hz, |i| i.logged_hz);
    Some(match c.source_hz {
        Some(src) => format!(
            "samples of fusions: logged at {}, source at {}",
            hz(logged),
            hz(src)
        ),
        None => format!("samples of fusions: logged at {}", hz(logged)),
    })
}

/// The EKF's own word on a channel, one line: test ratio, gate, rejections.
pub(super) fn ekf_line(c: &Px4Channel) -> Option<String> {
    let mut parts = Vec::new();
    if let Some(t) = c.test_ratio_mean {
        parts.push(format!("mean test ratio {}", num(t)));
    }
    if let Some(g) = c.gate {
        parts.push(format!("gate {} σ", num(g)));
    }
    if let Some(r) = c.rejected {
        parts.push(format!("{} rejected", count(r as u64, "update")));
    }
    (!parts.is_empty()).then(|| parts.join(", "))
}

/// The PX4 information of the report's logs (one per PX4 source).
pub(super) fn infos(r: &NisReport) -> impl Iterator<Item = (&str, &Px4Info)> {
    r.sources
        .iter()
        .filter_map(|s| s.px4.as_ref().map(|p| (s.path.as_str(), p)))
}

/// The PX4 information a sensor comes from: the only PX4 source, or the first (several
/// PX4 logs judged together name their channels alike).
pub(super) fn info_for(r: &NisReport) -> Option<&Px4Info> {
    infos(r).next().map(|(_, p)| p)
}

fn opt(v: Option<f64>) -> String {
    v.map_or_else(|| "–".into(), num)
}

fn channel_row(o: &mut String, info: &Px4Info, s: &SensorReport, c: &Px4Channel) {
    let mut note = fusion_note(Some(info), &s.name, c).unwrap_or_default();
    if c.inactive > 0 {
        if !note.is_empty() {
            note.push_str("; ");
        }
        let _ = write!(
            note,
            "{} while the source was off not judged",
            count(c.inactive as u64, "update")
        );
    }
    let _ = writeln!(
        o,
        "<tr><td><code>{}</code></td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td><td class=\"note\">{}</td></tr>",
        escape(&s.name),
        escape(&c.source),
        s.updates,
        num(s.nis.mean),
        num(s.nis.target),
        opt(c.test_ratio_mean),
        opt(c.gate),
        c.rejected.map_or_else(|| "–".into(), |r| r.to_string()),
        num(c.update_hz),
        opt(c.source_hz),
        opt(c.active_s),
        c.noise_param
            .as_deref()
            .map_or_else(|| "–".into(), |p| format!("<code>{}</code>", escape(p))),
        escape(&note)
    );
}

fn instances(o: &mut String, info: &Px4Info) {
    if info.instances.is_empty() {
        return;
    }
    o.push_str("<table><tr><th>instance</th><th>topics</th><th>rows</th><th>logged at</th><th>primary for</th></tr>");
    for i in &info.instances {
        let _ = write!(
            o,
            "<tr><td>ekf{}</td><td><code>{}</code></td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>",
            i.index,
            escape(&i.topics),
            i.rows,
            hz(i.logged_hz),
            i.primary_s
                .map_or_else(|| "not logged".into(), |p| format!("{} s", trimmed(p)))
        );
    }
    o.push_str("</table>\n");
}

fn events(o: &mut String, info: &Px4Info) {
    if info.events.is_empty() && info.param_changes.is_empty() {
        return;
    }
    let mut lines: Vec<String> = info
        .events
        .iter()
        .map(|e| format!("{} s: {}", trimmed(e.time), escape(&e.what)))
        .collect();
    lines.extend(info.param_changes.iter().map(|(t, name, v)| {
        format!(
            "{} s: parameter <code>{}</code> set to {}",
            trimmed(*t),
            escape(name),
            num(*v)
        )
    }));
    let head = format!(
        "Events ({}, marked on the time plots)",
        count(lines.len() as u64, "event")
    );
    let list = format!("<ul><li>{}</li></ul>", lines.join("</li><li>"));
    if lines.len() > EVENTS_INLINE {
        let _ = writeln!(o, "<details><summary>{head}</summary>{list}</details>");
    } else {
        let _ = writeln!(o, "<p>{head}:</p>{list}");
    }
}

/// The PX4 section, when a source is a PX4 log.
pub(super) fn section(o: &mut String, r: &NisReport) {
    let all: Vec<(&str, &Px4Info)> = infos(r).collect();
    if all.is_empty() {
        return;
    }
    o.push_str("<h2 id=\"px4\">PX4 estimator</h2>\n");
    for (path, info) in all {
        let _ = writeln!(
            o,
            "<p><code>{}</code>: innovations published by <b>{}</b>{}{}. Times are seconds since the log's start (its header's timestamp, {} µs after boot).</p>",
            escape(path),
            escape(&info.publisher),
            info.version
                .as_deref()
                .map_or_else(String::new, |v| format!(", PX4 {}", escape(v))),
            if info.publisher_evidence.is_empty() {
                String::new()
            } else {
                format!(" ({})", escape(&info.publisher_evidence))
            },
            info.time_origin_us
        );
        instances(o, info);
        if !info.not_judged.is_empty() {
            let _ = writeln!(
                o,
                "<h3>Not judged ({})</h3><ul>",
                count(info.not_judged.len() as u64, "channel")
            );
            for n in &info.not_judged {
                let _ = writeln!(
                    o,
                    "<li><code>{}</code> ({}): {}</li>",
                    escape(&n.name),
                    count(n.updates as u64, "update"),
                    escape(&n.reason)
                );
            }
            o.push_str("</ul>\n");
        }
        events(o, info);
    }
    if let Some(first) = info_for(r) {
        let judged: Vec<(&SensorReport, &Px4Channel)> = r
            .sensors
            .iter()
            .filter_map(|s| s.px4.as_ref().map(|c| (s, c)))
            .collect();
        if !judged.is_empty() {
            o.push_str("<h3>Channels judged, beside the EKF's own tests</h3>");
            o.push_str("<div class=\"wide\"><table><tr><th>channel</th><th>aiding source</th><th>updates</th><th>NIS average</th><th>expected</th><th>EKF mean test ratio</th><th>gate (σ)</th><th>EKF rejected</th><th>updates/s</th><th>source logged (Hz)</th><th>source active (s)</th><th>noise parameter</th><th>note</th></tr>\n");
            for (s, c) in judged {
                channel_row(o, first, s, c);
            }
            o.push_str("</table></div>\n");
        }
    }
    // A process-noise line ("decrease EKF2_ACC_NOISE") comes from every channel that blames
    // Q: one line per distinct advice, with the channels behind it.
    let mut advice: Vec<(&str, Vec<&str>)> = Vec::new();
    for s in &r.sensors {
        for p in &s.parameters {
            match advice.iter_mut().find(|(t, _)| *t == p.text) {
                Some((_, from)) => from.push(&s.name),
                None => advice.push((&p.text, vec![&s.name])),
            }
        }
    }
    if !advice.is_empty() {
        o.push_str("<h3>EKF2 parameters</h3><p>In EKF2's own terms (EKF2 inflates some variances internally: a GNSS receiver's reported accuracy, the range finder's distance scaling, baro ground effect; treat the values as a starting point).</p><ul>");
        for (a, from) in advice {
            let _ = write!(
                o,
                "<li><code>{}</code> ({})</li>",
                escape(a),
                escape(&from.join(", "))
            );
        }
        o.push_str("</ul>\n");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fusion_note_names_the_logged_and_the_source_rate() {
        let c = Px4Channel {
            sampled: true,
            update_hz: 4.9,
            source_hz: Some(18.8),
            ..Px4Channel::default()
        };
        let mut info = Px4Info::default();
        info.instances.push(crate::fieldlog::Px4Instance {
            index: 1,
            topics: "estimator_innovations".into(),
            rows: 10,
            logged_hz: 5.0,
            primary_s: None,
        });
        assert_eq!(
            fusion_note(Some(&info), "ekf1.baro_vpos", &c).as_deref(),
            Some("samples of fusions: logged at 5 Hz, source at 18.8 Hz")
        );
        // Without the instance, the channel's own rate.
        assert_eq!(
            fusion_note(None, "ekf1.baro_vpos", &c).as_deref(),
            Some("samples of fusions: logged at 4.9 Hz, source at 18.8 Hz")
        );
        let every = Px4Channel {
            sampled: false,
            ..c
        };
        assert!(fusion_note(Some(&info), "ekf1.baro_vpos", &every).is_none());
    }
}

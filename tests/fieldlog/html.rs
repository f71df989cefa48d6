//! Issue 23, the HTML report a PX4 engineer expects: per channel the innovation in its ±√S
//! band, the NIS on a log axis when it spans more than two decades, the log's own time
//! origin, takeoff / landing / aiding / primary events marked at their time, legends under
//! the plots (never over the data), and a PX4 section with the EKF's own tests, the
//! channels left unjudged and the EKF2 parameter advice.
//!
//! The report is built from a synthetic `NisReport` (the PX4 reader fills the same fields).
//! Set `ISSUE23_HTML_DUMP=/path.html` to write it out for a look in a browser.

use autotune::internals::fieldlog::{
    EventKind, LogSource, NisAnalyzer, NisReport, NisSettings, NotJudged, ParamAdvice, Px4Channel,
    Px4Event, Px4Info, Px4Instance, SensorInfo, Update,
};
use autotune::report::nis::html::nis_html;

/// Height of the chart part of every per-sensor plot (`NIS_SIZE.1`): the legend strip
/// starts below it.
const CHART_HEIGHT: f64 = 300.0;
/// The solid takeoff line's colour (`markers::FLIGHT`).
const FLIGHT: &str = "#282828";

/// Updates every 0.2 s over [0, 100] s; a deterministic zero-mean innovation cycling
/// through ±1.2, ±0.6, 0 standard deviations, `scale` multiplying its NIS.
fn push_channel(a: &mut NisAnalyzer, name: &str, sd: f64, scale: f64) {
    let i = a
        .sensor(SensorInfo {
            name: name.into(),
            components: vec!["z".into()],
            group: "ekf0".into(),
        })
        .expect("a sensor");
    for n in 0..=500 {
        let u = ((n * 7) % 5) as f64 * 0.6 - 1.2;
        let u = u * scale.sqrt();
        a.push(
            i,
            Update {
                time: n as f64 * 0.2,
                nis: u * u,
                dof: 1,
                u: Some(vec![u]),
                sd: Some(vec![sd]),
            },
        )
        .expect("a valid update");
    }
}

fn event(time: f64, what: &str, kind: EventKind) -> Px4Event {
    Px4Event {
        time,
        what: what.into(),
        kind,
    }
}

/// Three channels of ekf0 — a consistent baro, a heading whose NIS is 100× too small
/// (2.4 decades below its target), a channel whose name needs escaping — and a PX4 source
/// with two flights, aiding changes on two instances and a primary switch.
fn fixture() -> NisReport {
    let mut a = NisAnalyzer::new(NisSettings::default());
    push_channel(&mut a, "ekf0.baro_vpos", 2.0, 1.0);
    push_channel(&mut a, "ekf0.heading", 0.05, 0.01);
    push_channel(&mut a, "ekf0.odd<&\"name\">", 1.0, 1.0);
    let mut r = a.report();
    r.warnings
        .push("ekf1: every timestamp of ekf2_innovations is 0 <not judged>".into());
    let info = Px4Info {
        version: Some("v1.14.0".into()),
        publisher: "EKF2".into(),
        publisher_evidence: "SYS_MC_EST_GROUP = 2".into(),
        time_origin_us: 1_234_567,
        instances: vec![
            Px4Instance {
                index: 0,
                topics: "estimator_aid_src_baro_hgt".into(),
                rows: 501,
                logged_hz: 5.0,
                primary_s: Some(61.5),
            },
            Px4Instance {
                index: 1,
                topics: "estimator_aid_src_baro_hgt".into(),
                rows: 501,
                logged_hz: 5.0,
                primary_s: Some(38.5),
            },
        ],
        events: vec![
            event(5.0, "ekf0: GPS on", EventKind::Aiding),
            event(12.0, "ekf1: GPS on", EventKind::Aiding),
            event(20.0, "takeoff", EventKind::Takeoff),
            event(50.0, "landing", EventKind::Landing),
            event(60.0, "takeoff", EventKind::Takeoff),
            event(61.5, "primary: ekf1", EventKind::Primary),
            event(90.0, "landing", EventKind::Landing),
        ],
        not_judged: vec![NotJudged {
            name: "ekf0.gps_hpos[0]".into(),
            reason: "fake-position fusion: no horizontal aiding source was active".into(),
            updates: 480,
        }],
        ..Px4Info::default()
    };
    r.sources = vec![LogSource {
        path: "/logs/flight.ulg".into(),
        format: "px4-ulog".into(),
        rows: 1503,
        skipped_rows: 0,
        notes: Vec::new(),
        px4: Some(info),
    }];
    r.sensors[0].px4 = Some(Px4Channel {
        name: "ekf0.baro_vpos".into(),
        source: "barometric height".into(),
        test_ratio_mean: Some(0.031),
        gate: Some(5.0),
        rejected: Some(3),
        update_hz: 5.0,
        source_hz: Some(18.8),
        sampled: true,
        mean_s: 4.0,
        noise_param: Some("EKF2_BARO_NOISE".into()),
        ..Px4Channel::default()
    });
    r.sensors[0].parameters.push(ParamAdvice {
        param: "EKF2_BARO_NOISE".into(),
        unit: "m".into(),
        value: Some(3.5),
        suggested: Some(2.4),
        text: "EKF2_BARO_NOISE = 3.5 m → about 2.4 m".into(),
    });
    // A process-noise line that two channels both give.
    for i in [0, 1] {
        r.sensors[i].parameters.push(ParamAdvice {
            param: "EKF2_ACC_NOISE".into(),
            unit: "m/s²".into(),
            value: Some(0.35),
            suggested: None,
            text: "decrease EKF2_ACC_NOISE (now 0.350 m/s²)".into(),
        });
    }
    r
}

fn html() -> String {
    let h = nis_html(&fixture());
    if let Ok(path) = std::env::var("ISSUE23_HTML_DUMP") {
        std::fs::write(path, &h).expect("dump the report");
    }
    h
}

/// The sensor's section (from its heading to the next one).
fn section(html: &str, i: usize) -> &str {
    let start = html
        .find(&format!("<section id=\"sensor-{i}\""))
        .expect("the section");
    let end = html[start..].find("</section>").expect("its end") + start;
    &html[start..end]
}

/// The SVG documents of a section, in order.
fn svgs(section: &str) -> Vec<&str> {
    section
        .match_indices("<svg")
        .map(|(at, _)| {
            let end = section[at..].find("</svg>").expect("closed") + at + "</svg>".len();
            &section[at..end]
        })
        .collect()
}

fn attr(node: roxmltree::Node<'_, '_>, name: &str) -> f64 {
    node.attribute(name)
        .and_then(|v| v.parse().ok())
        .unwrap_or(f64::NAN)
}

/// The x of each solid vertical polyline drawn in `colour`.
fn vertical_lines(svg: &str, colour: &str) -> Vec<f64> {
    let doc = roxmltree::Document::parse(svg).expect("the plot is valid XML");
    doc.descendants()
        .filter(|n| n.has_tag_name("polyline") && n.attribute("stroke") == Some(colour))
        .filter_map(|n| {
            let pts: Vec<(f64, f64)> = n
                .attribute("points")?
                .split_whitespace()
                .filter_map(|p| {
                    let (x, y) = p.split_once(',')?;
                    Some((x.parse().ok()?, y.parse().ok()?))
                })
                .collect();
            (pts.len() == 2
                && (pts[0].0 - pts[1].0).abs() < 0.5
                && (pts[0].1 - pts[1].1).abs() > 50.0)
                .then_some(pts[0].0)
        })
        .collect()
}

/// `(text, x, y)` of every text element.
fn texts(svg: &str) -> Vec<(String, f64, f64)> {
    let doc = roxmltree::Document::parse(svg).expect("the plot is valid XML");
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| {
            (
                n.text().unwrap_or_default().trim().to_string(),
                attr(n, "x"),
                attr(n, "y"),
            )
        })
        .collect()
}

#[test]
fn issue23_each_channel_with_innovations_gets_its_innovation_plot_in_the_sqrt_s_band() {
    let h = html();
    for i in 0..3 {
        let s = section(&h, i);
        assert!(
            s.contains("innovation and ±√S"),
            "sensor {i}: no innovation plot"
        );
        assert_eq!(
            svgs(s).len(),
            4,
            "sensor {i}: NIS, innovation, histogram, ρ"
        );
        // The deterministic cycle puts 3 of 5 values within ±√S (0, ±0.6σ) and all within
        // ±2√S; the caption says so. The heading's innovations are 10× smaller than √S.
        let inside = if i == 1 { "100%" } else { "60%" };
        assert!(s.contains(&format!(
            "{inside} of the points lie inside ±√S and 100% inside ±2√S"
        )));
    }
    // The baro channel's innovations are in metres, its advice's unit.
    assert!(section(&h, 0).contains("innovation ν (m)"));
}

#[test]
fn issue23_the_nis_axis_turns_logarithmic_past_two_decades_and_not_before() {
    let h = html();
    // Consistent baro: median 0.36 to the largest 1.44, 0.6 decades: linear.
    let baro = section(&h, 0);
    assert!(!baro.contains("Logarithmic axis") && !baro.contains("NIS (log scale)"));
    // Heading 100× too small: median 0.0036 to the window interval's top 1.7, 2.3 decades:
    // logarithmic (the axis stayed linear up to three decades before issue 23), the zeros
    // at the floor.
    let heading = section(&h, 1);
    assert!(heading.contains("NIS (log scale)"));
    assert!(heading.contains("Logarithmic axis: the values span 2.3 decades"));
    assert!(heading.contains("drawn at the axis floor"));
}

#[test]
fn issue23_time_plots_run_on_the_logs_origin_with_events_at_their_time() {
    let h = html();
    let s = section(&h, 0);
    let plots = svgs(s);
    for svg in &plots[..2] {
        assert!(svg.contains("s since log start"));
        // Two takeoffs (20 s, 60 s) as solid lines; the series spans [0, 100] s, so the
        // second one is as far right of the first as 40/100 of the axis, and the first
        // 20/100 from the axis' start: the axis runs from x(20) − 20·k with k the px/s.
        let x = vertical_lines(svg, FLIGHT);
        assert_eq!(x.len(), 2, "two takeoff lines: {x:?}");
        let k = (x[1] - x[0]) / 40.0;
        assert!(k > 2.0, "the axis spans the plot: {k} px/s");
        let x0 = x[0] - 20.0 * k;
        // The y axis is drawn at the axis' start: a vertical black polyline there.
        let axis = vertical_lines(svg, "#000000");
        assert!(
            axis.iter().any(|a| (a - x0).abs() < 1.5),
            "takeoff at 20 s not 20% along the axis: axis lines {axis:?}, expected {x0}"
        );
        // Every kind labelled once in the legend, however many lines.
        let t = texts(svg);
        for label in [
            "takeoff",
            "landing",
            "aiding source change",
            "primary switch",
        ] {
            assert_eq!(
                t.iter().filter(|x| x.0 == label).count(),
                1,
                "legend entry {label}"
            );
        }
    }
    assert!(s.contains("Vertical lines mark takeoff (solid), landing (dashed)"));
}

#[test]
fn issue23_legends_sit_under_the_plot_never_over_the_data() {
    let h = html();
    let s = section(&h, 0);
    let legend_labels = [
        "NIS of an update",
        "window average",
        "expected",
        "innovation ν",
        "±√S",
        "takeoff",
        "χ²(1) density",
        "band of a white sequence (1-α)",
        "ρ of z",
    ];
    let mut seen = 0;
    for svg in svgs(s) {
        let doc = roxmltree::Document::parse(svg).expect("valid");
        let height = attr(doc.root_element(), "height");
        assert!(
            height > CHART_HEIGHT,
            "the SVG grows a strip for its legend"
        );
        for (text, _, y) in texts(svg) {
            if legend_labels.contains(&text.as_str()) {
                seen += 1;
                assert!(
                    y >= CHART_HEIGHT,
                    "legend entry {text} at y {y}, inside the chart (< {CHART_HEIGHT})"
                );
            }
        }
    }
    // Every label once, the time plots' takeoff twice.
    assert_eq!(seen, legend_labels.len() + 1, "the legends were found");
}

#[test]
fn issue23_the_px4_section_says_publisher_primary_ekf_tests_and_parameters() {
    let h = html();
    let px4 = &h[h.find("<h2 id=\"px4\">").expect("a PX4 section")
        ..h.find("<section id=\"sensor-0\"").expect("sections")];
    assert!(px4.contains("<b>EKF2</b>, PX4 v1.14.0 (SYS_MC_EST_GROUP = 2)"));
    assert!(px4.contains("1234567 µs after boot"));
    assert!(px4.contains("<td>ekf1</td>") && px4.contains("38.5 s"));
    assert!(px4.contains("<code>ekf0.gps_hpos[0]</code> (480 updates): fake-position fusion"));
    // The EKF's own test ratio, gate and rejections beside the NIS.
    assert!(px4.contains(
        "<td class=\"num\">0.03100</td><td class=\"num\">5.000</td><td class=\"num\">3</td>"
    ));
    assert!(px4.contains("samples of fusions: logged at 5 Hz, source at 18.8 Hz"));
    assert!(px4.contains("<code>EKF2_BARO_NOISE = 3.5 m → about 2.4 m</code> (ekf0.baro_vpos)"));
    // Advice that several channels give is listed once, with the channels behind it.
    assert_eq!(
        px4.matches("decrease EKF2_ACC_NOISE").count(),
        1,
        "one line per distinct parameter advice"
    );
    assert!(px4.contains(
        "<code>decrease EKF2_ACC_NOISE (now 0.350 m/s²)</code> (ekf0.baro_vpos, ekf0.heading)"
    ));
    assert!(px4.contains("20 s: takeoff"));
    // The same per channel, under its heading.
    let baro = section(&h, 0);
    assert!(baro.contains("mean test ratio 0.03100, gate 5.000 σ, 3 updates rejected"));
    assert!(baro.contains("EKF2 parameters: <code>EKF2_BARO_NOISE = 3.5 m → about 2.4 m</code>"));
    // The warnings come before the tables.
    let w = h.find("class=\"warnings\"").expect("warnings");
    assert!(w < h.find("<h2>Sensors</h2>").expect("sensors"));
    assert!(h.contains("is 0 &lt;not judged&gt;"));
}

#[test]
fn issue23_channel_names_are_escaped_everywhere() {
    let h = html();
    assert!(!h.contains("odd<&"), "a raw channel name reached the HTML");
    assert!(h.contains("odd&lt;&amp;&quot;name&quot;&gt;"));
    for svg in svgs(section(&h, 2)) {
        roxmltree::Document::parse(svg).expect("every plot stays valid XML");
    }
    assert!(!h.contains("NaN") && !h.contains("plot unavailable"));
}

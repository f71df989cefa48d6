//! Reports people look at: HTML with SVG plots, terminal behaviour, JUnit structure.

use crate::common;

use std::path::Path;
use std::process::Command as StdCommand;

use assert_cmd::Command;
use common::problem_path;

fn autotune() -> Command {
    Command::cargo_bin("autotune").unwrap()
}

/// The `<svg>…</svg>` documents inside an HTML page.
fn svgs(html: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = html;
    while let Some(start) = rest.find("<svg") {
        let end =
            rest[start..].find("</svg>").expect("every svg is closed") + start + "</svg>".len();
        out.push(&rest[start..end]);
        rest = &rest[end..];
    }
    out
}

fn texts(doc: &roxmltree::Document) -> Vec<String> {
    doc.descendants()
        .filter(|n| n.has_tag_name("text"))
        .filter_map(|n| n.text().map(|s| s.trim().to_string()))
        .collect()
}

fn tune_report(dir: &Path) -> String {
    autotune()
        .arg("tune")
        .arg(problem_path("cv2d"))
        .arg("--out")
        .arg(dir.join("cv2d.toml"))
        .arg("--report")
        .arg(dir.join("report"))
        .assert()
        .code(0);
    for f in ["report.html", "report.md", "report.json"] {
        assert!(dir.join("report").join(f).is_file(), "{f} missing");
    }
    std::fs::read_to_string(dir.join("report/report.html")).unwrap()
}

#[test]
fn html_report_is_self_contained_with_well_formed_plots() {
    let dir = tempfile::tempdir().unwrap();
    let html = tune_report(dir.path());
    assert!(html.starts_with("<!DOCTYPE html>"));
    assert!(!html.contains("<script"), "no JavaScript");
    // Nothing is fetched: the only URL is the SVG namespace.
    let urls = html.matches("http").count();
    assert_eq!(
        urls,
        html.matches("http://www.w3.org/2000/svg").count(),
        "external reference in the report"
    );
    let plots = svgs(&html);
    // ANEES and ANIS (initial and tuned), components (2), whiteness (2), objective.
    assert_eq!(plots.len(), 9);
    let mut statistic_plots = 0;
    for svg in &plots {
        let doc = roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("malformed SVG: {e}"));
        let t = texts(&doc);
        if t.iter()
            .any(|s| s.starts_with("ANEES_k,") || s.starts_with("ANIS_k,"))
        {
            statistic_plots += 1;
            // The band: a filled grey polygon; the data: a black polyline with one point per
            // step (200 steps); the target: a dashed line; the legend names all three.
            let band = doc
                .descendants()
                .filter(|n| n.has_tag_name("polygon") && n.attribute("fill") == Some("#D2D2D2"))
                .count();
            assert_eq!(band, 1, "one band polygon");
            let swatch = doc
                .descendants()
                .any(|n| n.has_tag_name("rect") && n.attribute("fill") == Some("#D2D2D2"));
            assert!(swatch, "the band's legend swatch");
            let data = doc
                .descendants()
                .filter(|n| n.has_tag_name("polyline") && n.attribute("stroke") == Some("#000000"))
                .any(|n| {
                    n.attribute("points")
                        .is_some_and(|p| p.split_whitespace().count() >= 200)
                });
            assert!(data, "no data series with 200 points");
            for label in ["per-step interval [r1, r2]", "DOF target"] {
                assert!(
                    t.iter().any(|s| s.starts_with(label)),
                    "legend lacks {label}: {t:?}"
                );
            }
            assert!(t.iter().any(|s| s == "time step k"), "x axis label");
            assert!(
                t.iter().any(|s| s.contains("(dimensionless)")),
                "y axis label with unit"
            );
        }
    }
    assert_eq!(statistic_plots, 4);
    let md = std::fs::read_to_string(dir.path().join("report/report.md")).unwrap();
    assert!(md.contains("## Recommendations"));
}

#[test]
fn check_writes_the_three_report_files_too() {
    let dir = tempfile::tempdir().unwrap();
    autotune()
        .arg("check")
        .arg(problem_path("cv1d"))
        .arg("--quiet")
        .arg("--report")
        .arg(dir.path())
        .assert()
        .code(1);
    let html = std::fs::read_to_string(dir.path().join("report.html")).unwrap();
    assert_eq!(svgs(&html).len(), 4);
    for svg in svgs(&html) {
        roxmltree::Document::parse(svg).unwrap();
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.path().join("report.json")).unwrap())
            .unwrap();
    assert_eq!(json["report"]["verdict"], "overconfident");
    assert!(
        std::fs::read_to_string(dir.path().join("report.md"))
            .unwrap()
            .contains("Verdict")
    );
}

#[test]
fn html_opens_in_headless_chromium_without_network() {
    // Needs a Chromium; .ci/run installs Debian's and sets AUTOTUNE_REQUIRE_CHROMIUM=1 so
    // that the test cannot pass by skipping there.
    let chromium = ["chromium", "chromium-browser"].into_iter().find(|c| {
        StdCommand::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
    });
    let Some(chromium) = chromium else {
        assert!(
            std::env::var_os("AUTOTUNE_REQUIRE_CHROMIUM").is_none(),
            "Chromium is required but not installed"
        );
        eprintln!("skipped: no chromium on PATH");
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    tune_report(dir.path());
    let url = format!("file://{}", dir.path().join("report/report.html").display());
    let profile = dir.path().join("profile");
    let flags = [
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        // No network at all: every host resolves nowhere.
        "--host-resolver-rules=MAP * ~NOTFOUND",
    ];
    let dom = StdCommand::new(chromium)
        .args(flags)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .unwrap();
    assert!(dom.status.success());
    let dom = String::from_utf8_lossy(&dom.stdout);
    assert_eq!(
        dom.matches("<svg").count(),
        9,
        "the browser's DOM has all plots"
    );
    let png = dir.path().join("shot.png");
    let shot = StdCommand::new(chromium)
        .args(flags)
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--window-size=1400,2600")
        .arg(format!("--screenshot={}", png.display()))
        .arg(&url)
        .output()
        .unwrap();
    assert!(shot.status.success());
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[1..4], b"PNG");
    // A blank page compresses to a few kilobytes; plots and tables do not.
    assert!(
        bytes.len() > 50_000,
        "screenshot is only {} bytes",
        bytes.len()
    );
}

#[test]
fn no_escape_codes_when_piped_or_with_no_color_and_quiet_is_silent() {
    let truth = ["--set", "q_accel=0.5", "--set", "r_pos=1"];
    // Piped (assert_cmd captures stdout): plain text.
    let out = autotune()
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(truth)
        .assert()
        .code(0);
    assert!(!String::from_utf8_lossy(&out.get_output().stdout).contains('\u{1b}'));
    // On a terminal (util-linux `script` gives the command a pseudo-terminal): colour, unless
    // NO_COLOR is set.
    let bin = assert_cmd::cargo::cargo_bin("autotune");
    let cmd = format!(
        "{} check {} --set q_accel=0.5 --set r_pos=1",
        bin.display(),
        problem_path("cv1d").display()
    );
    if let Ok(tty) = StdCommand::new("script")
        .args(["-qec", &cmd, "/dev/null"])
        .env_remove("NO_COLOR")
        .output()
    {
        assert!(
            String::from_utf8_lossy(&tty.stdout).contains("\u{1b}[1;32mverdict: consistent"),
            "colour on a terminal"
        );
        let plain = StdCommand::new("script")
            .args(["-qec", &cmd, "/dev/null"])
            .env("NO_COLOR", "1")
            .output()
            .unwrap();
        let text = String::from_utf8_lossy(&plain.stdout);
        assert!(
            text.contains("verdict: consistent") && !text.contains('\u{1b}'),
            "NO_COLOR: {text}"
        );
    }
    // --quiet: nothing at all on success.
    autotune()
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(truth)
        .arg("--quiet")
        .assert()
        .code(0)
        .stdout("")
        .stderr("");
    let dir = tempfile::tempdir().unwrap();
    autotune()
        .arg("tune")
        .arg(problem_path("cv1d"))
        .arg("--quiet")
        .arg("--out")
        .arg(dir.path().join("t.toml"))
        .assert()
        .code(0)
        .stdout("")
        .stderr("");
}

#[test]
fn junit_has_the_common_schema_shape() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("junit.xml");
    autotune()
        .arg("check")
        .arg(problem_path("dcmotor"))
        .arg("--quiet")
        .arg("--junit")
        .arg(&path)
        .assert()
        .code(1);
    let xml = std::fs::read_to_string(&path).unwrap();
    let doc = roxmltree::Document::parse(&xml).unwrap();
    let root = doc.root_element();
    assert!(root.has_tag_name("testsuites"));
    let suites: Vec<_> = root.children().filter(|n| n.is_element()).collect();
    assert_eq!(suites.len(), 1);
    let suite = suites[0];
    assert!(suite.has_tag_name("testsuite"));
    let cases: Vec<_> = suite.children().filter(|n| n.is_element()).collect();
    assert!(cases.iter().all(|c| c.has_tag_name("testcase")
        && c.attribute("name").is_some()
        && c.attribute("classname").is_some()));
    let failures: Vec<_> = cases
        .iter()
        .filter_map(|c| {
            c.children()
                .find(|n| n.has_tag_name("failure"))
                .map(|f| (c.attribute("name").unwrap(), f))
        })
        .collect();
    assert_eq!(
        suite.attribute("tests"),
        Some(cases.len().to_string().as_str())
    );
    assert_eq!(
        suite.attribute("failures"),
        Some(failures.len().to_string().as_str())
    );
    let names: Vec<&str> = failures.iter().map(|(n, _)| *n).collect();
    assert_eq!(names, ["time-averaged ANEES", "time-averaged ANIS"]);
    for (_, f) in &failures {
        let msg = f.attribute("message").unwrap();
        assert!(
            msg.contains("outside")
                && (msg.contains("overconfident") || msg.contains("underconfident")),
            "{msg}"
        );
    }
}

#[test]
fn long_checks_show_progress_only_on_a_terminal() {
    let args = [
        "--runs",
        "20000",
        "--steps",
        "1000",
        "--set",
        "q_accel=0.5",
        "--set",
        "r_pos=1",
    ];
    // Piped: nothing on stderr.
    autotune()
        .arg("check")
        .arg(problem_path("cv1d"))
        .args(args)
        .assert()
        .stderr("");
    let bin = assert_cmd::cargo::cargo_bin("autotune");
    let cmd = format!(
        "{} check {} {}",
        bin.display(),
        problem_path("cv1d").display(),
        args.join(" ")
    );
    if let Ok(tty) = StdCommand::new("script")
        .args(["-qec", &cmd, "/dev/null"])
        .output()
    {
        let text = String::from_utf8_lossy(&tty.stdout);
        assert!(
            text.contains("runs,") && text.contains("ETA"),
            "no progress bar on a terminal: {text}"
        );
    }
}

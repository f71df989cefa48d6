//! Issue #25: a worker that sums its own records (through `WorkerChunk`, its C ABI or its
//! Python package) answers with their sums, and autotune's statistics equal the records
//! path's bit for bit. A relay worker (`tests/data/workers/relay_worker.py`) answers each
//! request from a table this test writes: the records as JSON Lines, or the sums the library
//! computed from the very same records; a spoiled sums answer is a one-line error, exit 2.

use std::collections::BTreeMap;
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};

use crate::common;
use autotune::internals::capi;
use autotune::internals::experiment::Experiment;
use autotune::internals::external::WorkerChunk;
use autotune::internals::problem::Problem;
use autotune::internals::records::{
    Layout, SensorLayout, StateLayout, StepRecord, parse_record_line,
};
use common::autotune;

const STEPS: usize = 30;
const RUNS: usize = 200;

/// A small deterministic generator (splitmix64), so the records are the same in every run
/// of the test.
struct Mix(u64);

impl Mix {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }
}

/// Run i's records as JSON Lines: a 2-state error with its covariance every step, sensor
/// `a` (1 component) every step, sensor `b` (2 components) every third step; run 5 diverges
/// at step 7.
fn run_lines(i: usize) -> Vec<String> {
    let mut g = Mix(i as u64 * 7919 + 1);
    let mut out = Vec::new();
    for k in 1..=STEPS {
        if i == 5 && k == 7 {
            out.push(format!(
                r#"{{"run": {i}, "step": {k}, "diverged": "P lost positive definiteness"}}"#
            ));
            break;
        }
        let (p11, p22, p12) = (1.0 + g.next().abs(), 2.0 + g.next().abs(), 0.3 * g.next());
        let mut rec = serde_json::json!({
            "run": i, "step": k,
            "e": [g.next() * 1.5, g.next() * 2.0],
            "P": [[p11, p12], [p12, p22]],
            "nu_a": [g.next()], "S_a": [[0.5 + g.next().abs()]],
        });
        if k % 3 == 0 {
            let s12 = 0.2 * g.next();
            rec["nu_b"] = serde_json::json!([g.next(), g.next() * 3.0]);
            rec["S_b"] = serde_json::json!([[1.0 + g.next().abs(), s12], [s12, 4.0]]);
        }
        out.push(rec.to_string());
    }
    out
}

fn problem_text(dir: &Path, table: &Path, mode: &str, workers: usize) -> PathBuf {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/workers/relay_worker.py");
    let text = format!(
        r#"name = "relay_{mode}"
state_names = ["x", "v"]

[montecarlo]
runs = {RUNS}
steps = {STEPS}
seed = 3

[external]
command = ["python3", "{script}", "{table}", "{mode}"]
sensors = {{ a = ["pos"], b = ["pos", "vel"] }}
workers = {workers}
timeout = 20

[params.q]
value = 1.0

[params.r]
value = 1.0
"#,
        script = script.display(),
        table = table.display(),
    );
    let path = dir.join(format!("relay_{mode}_{workers}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// The request fields a worker library reads, as autotune states them for this layout.
fn request_fields(lags: usize) -> serde_json::Value {
    serde_json::json!({
        "lags": lags,
        "layout": {"state": 2, "sensors": [{"name": "a", "dim": 1}, {"name": "b", "dim": 2}]}
    })
}

/// The records of `runs`, parsed as autotune parses an inline answer.
fn records(runs: std::ops::Range<usize>, layout: &Layout) -> Vec<StepRecord> {
    runs.flat_map(run_lines)
        .map(|l| parse_record_line(&l, layout).unwrap())
        .collect()
}

/// A request line for `runs`, with the fields a worker library reads.
fn request(runs: std::ops::Range<usize>, lags: usize) -> String {
    let mut r = request_fields(lags);
    r["id"] = 9.into();
    r["runs"] = serde_json::json!([runs.start, runs.end]);
    r["steps"] = STEPS.into();
    r["theta"] = serde_json::json!({"q": 1.0, "r": 1.0});
    r.to_string()
}

/// The sums answer of `runs` through `WorkerChunk`, its text after `"sums":"`.
fn sums_of(runs: std::ops::Range<usize>, lags: usize, layout: &Layout) -> String {
    let mut chunk = WorkerChunk::from_request(&request(runs.clone(), lags)).unwrap();
    for r in records(runs, layout) {
        chunk.push(r).unwrap();
    }
    let line = chunk.answer().unwrap();
    let v: serde_json::Value = serde_json::from_str(&line).unwrap();
    assert_eq!(v["id"], 9);
    v["sums"].as_str().unwrap().to_string()
}

/// Write the relay table: every chunk of 64 runs, and the two halves of the first chunk the
/// seed-contract check asks for.
fn write_table(dir: &Path, lags: usize, layout: &Layout) -> PathBuf {
    let mut ranges: Vec<std::ops::Range<usize>> = (0..RUNS)
        .step_by(64)
        .map(|a| a..(a + 64).min(RUNS))
        .collect();
    ranges.extend([32..64, 0..32]);
    let mut answers = BTreeMap::new();
    for r in ranges {
        let lines: Vec<String> = r.clone().flat_map(run_lines).collect();
        answers.insert(
            format!("{},{}", r.start, r.end),
            serde_json::json!({"records": lines, "sums": sums_of(r, lags, layout)}),
        );
    }
    let mut table = request_fields(lags);
    let table = serde_json::json!({"request": table.take(), "steps": STEPS, "answers": answers});
    let path = dir.join("table.json");
    std::fs::write(&path, table.to_string()).unwrap();
    path
}

fn layout_and_lags(dir: &Path) -> (Layout, usize) {
    // The layout and lags autotune itself derives from the problem file.
    let p = Problem::load(&problem_text(dir, Path::new("unused"), "records", 1)).unwrap();
    let lags = p.mc().lags();
    let sensor = |name: &str, dim| SensorLayout {
        name: name.into(),
        dim,
        components: true,
    };
    let layout = Layout {
        state: Some(StateLayout {
            dim: 2,
            components: true,
        }),
        sensors: vec![sensor("a", 1), sensor("b", 2)],
    };
    (layout, lags)
}

/// The statistics from sums answers equal those from the same records answered inline, bit
/// for bit (compared through their shortest round-trip digits, which tell every bit of a
/// finite double apart), on one and two workers, with the seed-contract check on.
#[test]
fn sums_answers_equal_the_records_path_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (layout, lags) = layout_and_lags(dir.path());
    let table = write_table(dir.path(), lags, &layout);
    let sums = |mode: &str, workers: usize| {
        let p = Problem::load(&problem_text(dir.path(), &table, mode, workers)).unwrap();
        p.monte_carlo(&[1.0, 1.0], p.mc()).unwrap()
    };
    let by_records = sums("records", 2);
    assert_eq!(by_records.runs(), RUNS);
    assert_eq!(
        by_records.diverged_runs(),
        1,
        "run 5's divergence is counted"
    );
    assert!(by_records.white_pairs().iter().any(|&p| p > 0.0));
    for workers in [1, 2] {
        let by_sums = sums("sums", workers);
        assert_eq!(
            format!("{by_sums:?}"),
            format!("{by_records:?}"),
            "{workers} worker(s)"
        );
    }
}

/// The C ABI, step by step (sensors given in any order) or as NumPy-layout arrays, answers
/// what `WorkerChunk` answers.
#[test]
fn the_c_abi_answers_what_the_library_answers() {
    let dir = tempfile::tempdir().unwrap();
    let (layout, lags) = layout_and_lags(dir.path());
    let runs = 64..128;
    let want = sums_of(runs.clone(), lags, &layout);
    let req = CString::new(request(runs.clone(), lags)).unwrap();
    let answer_text = |c: *mut capi::AutotuneChunk| unsafe {
        let s = capi::autotune_chunk_answer(c);
        assert!(
            !s.is_null(),
            "{:?}",
            CStr::from_ptr(capi::autotune_last_error())
        );
        let line = CStr::from_ptr(s).to_str().unwrap().to_string();
        capi::autotune_string_free(s);
        let v: serde_json::Value = serde_json::from_str(&line).unwrap();
        v["sums"].as_str().unwrap().to_string()
    };
    // Step by step, sensor b before sensor a.
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    assert!(!c.is_null());
    for r in records(runs.clone(), &layout) {
        let (run, step) = (r.run, r.step);
        if let Some(why) = &r.diverged {
            let why = CString::new(why.as_str()).unwrap();
            assert_eq!(
                unsafe { capi::autotune_chunk_diverged(c, run, step, why.as_ptr()) },
                0
            );
            continue;
        }
        for (k, s) in r.sensors.iter().rev() {
            let autotune::internals::records::SensorRecord::Raw { nu, s } = s else {
                unreachable!()
            };
            let name = CString::new(layout.sensors[*k].name.as_str()).unwrap();
            let rc = unsafe {
                capi::autotune_chunk_sensor(c, run, step, name.as_ptr(), nu.as_ptr(), s.as_ptr())
            };
            assert_eq!(rc, 0);
        }
        let Some(autotune::internals::records::StateRecord::Raw { e, p }) = &r.state else {
            unreachable!()
        };
        assert_eq!(
            unsafe { capi::autotune_chunk_state(c, run, step, e.as_ptr(), p.as_ptr()) },
            0
        );
    }
    assert_eq!(answer_text(c), want, "step by step");

    // As arrays: NaN where a sensor did not measure, and `diverged` per run.
    let n = runs.len();
    let mut e = vec![f64::NAN; n * STEPS * 2];
    let mut p = vec![f64::NAN; n * STEPS * 4];
    let mut nu_a = vec![f64::NAN; n * STEPS];
    let mut s_a = vec![f64::NAN; n * STEPS];
    let mut nu_b = vec![f64::NAN; n * STEPS * 2];
    let mut s_b = vec![f64::NAN; n * STEPS * 4];
    let mut diverged = vec![0.0; n];
    for r in records(runs.clone(), &layout) {
        let (i, t) = (r.run - runs.start, r.step - 1);
        let at = i * STEPS + t;
        if r.diverged.is_some() {
            diverged[i] = r.step as f64;
            continue;
        }
        if let Some(autotune::internals::records::StateRecord::Raw { e: ee, p: pp }) = &r.state {
            e[at * 2..at * 2 + 2].copy_from_slice(ee);
            p[at * 4..at * 4 + 4].copy_from_slice(pp);
        }
        for (k, s) in &r.sensors {
            let autotune::internals::records::SensorRecord::Raw { nu, s } = s else {
                unreachable!()
            };
            if *k == 0 {
                nu_a[at] = nu[0];
                s_a[at] = s[0];
            } else {
                nu_b[at * 2..at * 2 + 2].copy_from_slice(nu);
                s_b[at * 4..at * 4 + 4].copy_from_slice(s);
            }
        }
    }
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    let arrays: [(&str, Vec<usize>, &[f64]); 7] = [
        ("e", vec![n, STEPS, 2], &e),
        ("P", vec![n, STEPS, 2, 2], &p),
        ("nu_a", vec![n, STEPS, 1], &nu_a),
        ("S_a", vec![n, STEPS, 1, 1], &s_a),
        ("nu_b", vec![n, STEPS, 2], &nu_b),
        ("S_b", vec![n, STEPS, 2, 2], &s_b),
        ("diverged", vec![n], &diverged),
    ];
    for (name, shape, data) in arrays {
        let name = CString::new(name).unwrap();
        let rc = unsafe {
            capi::autotune_chunk_array(c, name.as_ptr(), shape.as_ptr(), shape.len(), data.as_ptr())
        };
        assert_eq!(rc, 0, "{:?}", unsafe {
            CStr::from_ptr(capi::autotune_last_error())
        });
    }
    assert_eq!(answer_text(c), want, "as arrays");
}

/// A run left out, a step out of order and a bad pointer are refused with a message, and
/// never crash the worker.
#[test]
fn the_c_abi_refuses_what_a_records_file_would_not_hold() {
    let dir = tempfile::tempdir().unwrap();
    let (layout, lags) = layout_and_lags(dir.path());
    let req = CString::new(request(0..4, lags)).unwrap();
    let last = || {
        unsafe { CStr::from_ptr(capi::autotune_last_error()) }
            .to_str()
            .unwrap()
            .to_string()
    };
    // Runs 0..3 only.
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    for r in records(0..3, &layout) {
        if let Some(autotune::internals::records::StateRecord::Raw { e, p }) = &r.state {
            unsafe { capi::autotune_chunk_state(c, r.run, r.step, e.as_ptr(), p.as_ptr()) };
        } else {
            let why = CString::new("x").unwrap();
            unsafe { capi::autotune_chunk_diverged(c, r.run, r.step, why.as_ptr()) };
        }
    }
    assert!(unsafe { capi::autotune_chunk_answer(c) }.is_null());
    assert!(last().contains("run 3"), "{}", last());
    // A step out of order.
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    let (e, p) = ([0.1, 0.2], [1.0, 0.0, 0.0, 1.0]);
    assert_eq!(
        unsafe { capi::autotune_chunk_state(c, 0, 1, e.as_ptr(), p.as_ptr()) },
        0
    );
    unsafe { capi::autotune_chunk_state(c, 0, 3, e.as_ptr(), p.as_ptr()) };
    let s = unsafe { capi::autotune_chunk_answer(c) };
    assert!(s.is_null());
    assert!(last().contains("step"), "{}", last());
    // A run outside the request or a step outside 1..=T is refused at the call (-1, the
    // argument named), by every call that takes them (issue 37, item 5).
    let why = CString::new("x").unwrap();
    let sensor = CString::new(layout.sensors[0].name.as_str()).unwrap();
    let m = layout.sensors[0].dim;
    let (nu, s) = (vec![0.1; m], {
        let mut s = vec![0.0; m * m];
        (0..m).for_each(|i| s[i * m + i] = 1.0);
        s
    });
    for (run, step, what) in [
        (4, 1, "run 4 is not one the request asks for (0..4)"),
        (usize::MAX, 1, "is not one the request asks for"),
        (0, 0, "step 0 is outside the request's steps 1..=30"),
        (0, STEPS + 1, "step 31 is outside"),
        (0, usize::MAX, "is outside the request's steps"),
    ] {
        for call in 0..3 {
            let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
            let code = match call {
                0 => unsafe { capi::autotune_chunk_state(c, run, step, e.as_ptr(), p.as_ptr()) },
                1 => unsafe {
                    capi::autotune_chunk_sensor(
                        c,
                        run,
                        step,
                        sensor.as_ptr(),
                        nu.as_ptr(),
                        s.as_ptr(),
                    )
                },
                _ => unsafe { capi::autotune_chunk_diverged(c, run, step, why.as_ptr()) },
            };
            assert_eq!(code, -1, "call {call}, run {run}, step {step}");
            assert!(last().contains(what), "call {call}: {}", last());
            unsafe { capi::autotune_chunk_free(c) };
        }
    }
    // NULL pointers, an unknown sensor, a request from before sums.
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    assert_eq!(
        unsafe { capi::autotune_chunk_state(c, 0, 1, std::ptr::null(), p.as_ptr()) },
        -1
    );
    assert!(last().contains("e is NULL"), "{}", last());
    let b = CString::new("radar").unwrap();
    assert_eq!(
        unsafe { capi::autotune_chunk_sensor(c, 0, 1, b.as_ptr(), e.as_ptr(), p.as_ptr()) },
        -1
    );
    assert!(last().contains("no sensor \"radar\""), "{}", last());
    unsafe { capi::autotune_chunk_free(c) };
    assert!(unsafe { capi::autotune_chunk_new(std::ptr::null()) }.is_null());
    // An array given twice, or of the wrong size for its shape.
    let c = unsafe { capi::autotune_chunk_new(req.as_ptr()) };
    let (name, shape, data) = (
        CString::new("e").unwrap(),
        [4usize, STEPS, 2],
        vec![0.0; 4 * STEPS * 2],
    );
    let add = |c| unsafe {
        capi::autotune_chunk_array(c, name.as_ptr(), shape.as_ptr(), 3, data.as_ptr())
    };
    assert_eq!(add(c), 0);
    assert_eq!(add(c), -1);
    assert!(last().contains("array e: given twice"), "{}", last());
    unsafe { capi::autotune_chunk_free(c) };
    let old = CString::new(r#"{"id":1,"runs":[0,4],"steps":30}"#).unwrap();
    assert!(unsafe { capi::autotune_chunk_new(old.as_ptr()) }.is_null());
    assert!(last().contains("older"), "{}", last());
}

/// A spoiled sums answer stops `check` with one line naming the command, the request and
/// what is wrong, exit 2, nothing judged.
#[test]
fn a_spoiled_sums_answer_is_a_one_line_error() {
    let dir = tempfile::tempdir().unwrap();
    let (layout, lags) = layout_and_lags(dir.path());
    let table = write_table(dir.path(), lags, &layout);
    for (mode, expect) in [
        ("flip", "nees_count is 1000000000, which no records give"),
        ("short", "'sums'"),
        ("text", "'sums' is not base64: not a string"),
    ] {
        let p = problem_text(dir.path(), &table, mode, 1);
        let (code, stdout, stderr) = autotune(&["check", p.to_str().unwrap()]);
        assert_eq!(code, Some(2), "{mode}: {stdout} {stderr}");
        assert!(stdout.is_empty(), "{mode}: {stdout}");
        assert_eq!(stderr.lines().count(), 1, "{mode}: {stderr}");
        assert!(stderr.contains("relay_worker.py"), "{mode}: {stderr}");
        assert!(
            stderr.contains(expect),
            "{mode}: expected {expect:?} in {stderr}"
        );
    }
}

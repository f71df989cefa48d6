//! Issue #12, item 1: `autotune check --records`. Hand-computed NEES and NIS read alike
//! from CSV, JSON Lines and `.npy` files (written here byte by byte from the NumPy format's
//! specification); malformed files name the file, the row or array and the field; and,
//! with python3 and numpy (required in CI), records written by the Python example agree
//! with the built-in problem to Monte Carlo precision and precomputed NEES/NIS with raw
//! e, P, ν, S.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::common;
use common::autotune;
use serde_json::Value;

/// `check --records FILES --json`, its exit code and report.
fn check_json(files: &[&Path], extra: &[&str]) -> (Option<i32>, Value) {
    let mut args = vec!["check", "--json"];
    args.extend(extra);
    args.push("--records");
    let names: Vec<String> = files.iter().map(|f| f.display().to_string()).collect();
    args.extend(names.iter().map(String::as_str));
    let (code, stdout, stderr) = autotune(&args);
    let v: Value = serde_json::from_str(&stdout)
        .unwrap_or_else(|e| panic!("{e}: stdout {stdout}\nstderr {stderr}"));
    (code, v)
}

fn per_step(v: &Value, stat: &str) -> Vec<Option<f64>> {
    v["report"][stat]["per_step"]
        .as_array()
        .unwrap()
        .iter()
        .map(Value::as_f64)
        .collect()
}

/// Two runs of two steps, two states, one sensor `r` of one component, not measured at
/// run 0's step 2. By hand: NEES 1.5, 4/3 (run 0) and 1, 2 (run 1); NIS 1 wherever
/// measured.
const E: [[[f64; 2]; 2]; 2] = [[[1.0, 2.0], [1.0, 0.0]], [[0.0, 1.0], [2.0, 2.0]]];
const P: [[[f64; 4]; 2]; 2] = [
    [[2.0, 0.0, 0.0, 4.0], [1.0, 0.5, 0.5, 1.0]],
    [[1.0, 0.0, 0.0, 1.0], [4.0, 0.0, 0.0, 4.0]],
];
const NU: [[f64; 2]; 2] = [[3.0, f64::NAN], [2.0, 1.0]];
const S: [[f64; 2]; 2] = [[9.0, 1.0], [4.0, 1.0]];

fn write_csv(dir: &Path) -> PathBuf {
    let mut t = String::from("run,step,e_1,e_2,P_1_1,P_1_2,P_2_2,nu_r_1,S_r_1_1\n");
    for r in 0..2 {
        for k in 0..2 {
            let (nu, s) = if NU[r][k].is_nan() {
                (String::new(), String::new())
            } else {
                (NU[r][k].to_string(), S[r][k].to_string())
            };
            t += &format!(
                "{r},{},{},{},{},{},{},{nu},{s}\n",
                k + 1,
                E[r][k][0],
                E[r][k][1],
                P[r][k][0],
                P[r][k][1],
                P[r][k][3]
            );
        }
    }
    let path = dir.join("hand.csv");
    std::fs::write(&path, t).unwrap();
    path
}

fn write_jsonl(dir: &Path) -> PathBuf {
    let mut t = String::new();
    for r in 0..2 {
        for k in 0..2 {
            let p = P[r][k];
            let mut o = serde_json::json!({
                "run": r, "step": k + 1, "e": E[r][k],
                "P": [[p[0], p[1]], [p[2], p[3]]],
            });
            if !NU[r][k].is_nan() {
                o["nu_r"] = serde_json::json!([NU[r][k]]);
                o["S_r"] = serde_json::json!([[S[r][k]]]);
            }
            t += &format!("{o}\n");
        }
    }
    let path = dir.join("hand.jsonl");
    std::fs::write(&path, t).unwrap();
    path
}

/// A `.npy` file (format version 1.0): magic, header length, the header dictionary padded
/// with spaces to a multiple of 64 bytes, then little-endian float64 data in C order.
fn write_npy(path: &Path, shape: &[usize], data: &[f64]) {
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape_text}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((header.len() as u16).to_le_bytes());
    bytes.extend(header.as_bytes());
    for v in data {
        bytes.extend(v.to_le_bytes());
    }
    std::fs::write(path, bytes).unwrap();
}

fn write_npy_set(dir: &Path) -> Vec<PathBuf> {
    let e: Vec<f64> = E.iter().flatten().flatten().copied().collect();
    let p: Vec<f64> = P.iter().flatten().flatten().copied().collect();
    let nu: Vec<f64> = NU.iter().flatten().copied().collect();
    let s: Vec<f64> = S.iter().flatten().copied().collect();
    let files = [
        ("e", vec![2, 2, 2], e),
        ("P", vec![2, 2, 2, 2], p),
        ("nu_r", vec![2, 2, 1], nu),
        ("S_r", vec![2, 2, 1, 1], s),
    ];
    files
        .into_iter()
        .map(|(name, shape, data)| {
            let path = dir.join(format!("{name}.npy"));
            write_npy(&path, &shape, &data);
            path
        })
        .collect()
}

#[test]
fn hand_computed_nees_and_nis_read_alike_from_csv_jsonl_and_npy() {
    let dir = tempfile::tempdir().unwrap();
    let csv = write_csv(dir.path());
    let jsonl = write_jsonl(dir.path());
    let npy = write_npy_set(dir.path());
    let npy_refs: Vec<&Path> = npy.iter().map(PathBuf::as_path).collect();
    let reports = [
        check_json(&[&csv], &["--gate", "mean"]).1,
        check_json(&[&jsonl], &["--gate", "mean"]).1,
        check_json(&npy_refs, &["--gate", "mean"]).1,
    ];
    for v in &reports {
        let nees = per_step(v, "nees");
        assert!((nees[0].unwrap() - 1.25).abs() < 1e-12, "{nees:?}");
        assert!(
            (nees[1].unwrap() - (4.0 / 3.0 + 2.0) / 2.0).abs() < 1e-12,
            "{nees:?}"
        );
        assert_eq!(per_step(v, "nis"), vec![Some(1.0), Some(1.0)]);
        assert_eq!(v["report"]["runs"], 2);
        assert_eq!(v["report"]["steps"], 2);
    }
    assert_eq!(
        reports[0]["report"], reports[1]["report"],
        "CSV vs JSON Lines"
    );
    assert_eq!(reports[0]["report"], reports[2]["report"], "CSV vs .npy");
}

/// A covariance the same in every run may leave out the runs axis, (T, n, n).
#[test]
fn a_covariance_shared_by_all_runs_may_leave_out_the_runs_axis() {
    let dir = tempfile::tempdir().unwrap();
    let e: Vec<f64> = E.iter().flatten().flatten().copied().collect();
    let p_shared: Vec<f64> = P[0].iter().flatten().copied().collect();
    let (ef, pf) = (dir.path().join("e.npy"), dir.path().join("P.npy"));
    write_npy(&ef, &[2, 2, 2], &e);
    write_npy(&pf, &[2, 2, 2], &p_shared);
    let (_, v) = check_json(&[&ef, &pf], &["--gate", "mean"]);
    // Run 1 against run 0's covariances: e = (0, 1) with P = diag(2, 4) gives 1/4; e = (2, 2)
    // with P = [[1, ½], [½, 1]] gives (4 − 4 + 4)/0.75.
    let nees = per_step(&v, "nees");
    assert!(
        (nees[0].unwrap() - (1.5 + 0.25) / 2.0).abs() < 1e-12,
        "{nees:?}"
    );
    assert!(
        (nees[1].unwrap() - (4.0 / 3.0 + 16.0 / 3.0) / 2.0).abs() < 1e-12,
        "{nees:?}"
    );
}

/// Each malformed file: exit 2, nothing on stdout, one line naming the file and where.
#[test]
fn malformed_records_name_the_file_the_row_and_the_field() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let head = "run,step,e_1,P_1_1\n";
    let cases: Vec<(&str, String, &[&str])> = vec![
        (
            "number.csv",
            format!("{head}0,1,0.5,1\n0,2,0.5,abc\n"),
            &["number.csv:3", "P_1_1", "'abc' is not a number"],
        ),
        (
            "column.csv",
            "run,step,e_1,e_3,P_1_1\n0,1,1,1,1\n".into(),
            &["column.csv:1", "header", "column e_2 missing"],
        ),
        (
            "unknown.csv",
            "run,step,e_1,P_1_1,Q_1_1\n0,1,1,1,1\n".into(),
            &["unknown column 'Q_1_1'"],
        ),
        (
            "twice.csv",
            format!("{head}0,1,1,1\n1,1,1,1\n0,1,1,1\n"),
            &["twice.csv:4", "run 0 appears twice"],
        ),
        (
            "gap.csv",
            format!("{head}0,1,1,1\n0,3,1,1\n"),
            &["gap.csv:3", "step 3 follows step 1"],
        ),
        (
            "short.csv",
            format!("{head}0,1,1,1\n0,2,1,1\n1,1,1,1\n"),
            &["run 1: ends at step 1 of 2"],
        ),
        (
            "nodof.csv",
            "run,step,nees\n0,1,3.2\n".into(),
            &["nees without nees_dof or e2p"],
        ),
        (
            "fields.csv",
            format!("{head}0,1,1\n"),
            &["fields.csv:2", "3 fields where the header has 4"],
        ),
        (
            "key.jsonl",
            "{\"run\":0,\"step\":1,\"e\":[1],\"P\":[[1]]}\n{\"run\":0,\"step\":2,\"foo\":1}\n"
                .into(),
            &["key.jsonl:2", "unknown key 'foo'"],
        ),
        (
            "json.jsonl",
            "{\"run\":0,\"step\":1,\"e\":[1],\"P\":[[1]]}\nnot json\n".into(),
            &["json.jsonl:2", "not JSON"],
        ),
        (
            "records.txt",
            "x".into(),
            &["records.txt", "not a records file"],
        ),
    ];
    for (name, text, expect) in cases {
        let path = d.join(name);
        std::fs::write(&path, text).unwrap();
        let (code, stdout, stderr) = autotune(&["check", "--records", path.to_str().unwrap()]);
        assert_eq!(code, Some(2), "{name}: {stdout}{stderr}");
        assert!(stdout.is_empty(), "{name}: {stdout}");
        assert_eq!(stderr.lines().count(), 1, "{name}: {stderr}");
        for e in expect {
            assert!(stderr.contains(e), "{name}: expected '{e}' in {stderr}");
        }
    }
    // A NumPy array of the wrong shape is named.
    let npy = d.join("npy");
    std::fs::create_dir(&npy).unwrap();
    write_npy(&npy.join("e.npy"), &[1, 2, 2], &[0.0; 4]);
    let cases: [(&[usize], usize, &[&str]); 2] = [
        (&[1, 2, 3, 3], 18, &["P is 3×3 but e has 2 entries"]),
        (&[1, 3, 2, 2], 12, &["array P", "differ from e's (1, 2)"]),
    ];
    for (shape, len, expect) in cases {
        write_npy(&npy.join("P.npy"), shape, &vec![1.0; len]);
        let (code, _, stderr) = autotune(&[
            "check",
            "--records",
            npy.join("e.npy").to_str().unwrap(),
            npy.join("P.npy").to_str().unwrap(),
        ]);
        assert_eq!(code, Some(2), "{stderr}");
        for e in expect {
            assert!(stderr.contains(e), "{shape:?}: expected '{e}' in {stderr}");
        }
    }
}

/// NaN covariances in records are a diverged filter: exit 1, not a bad file.
#[test]
fn nan_in_records_is_a_diverged_run() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nan.csv");
    std::fs::write(
        &path,
        "run,step,e_1,P_1_1\n0,1,0.5,1\n0,2,0.5,NaN\n1,1,0.1,1\n1,2,0.2,1\n",
    )
    .unwrap();
    let (code, stdout, _) = autotune(&["check", "--records", path.to_str().unwrap()]);
    assert_eq!(code, Some(1), "{stdout}");
    assert!(stdout.contains("diverged in 1 of 2 runs"), "{stdout}");
}

/// Whether python3 with numpy can run the Python example; required where
/// AUTOTUNE_REQUIRE_PYTHON is set (CI installs numpy).
pub(crate) fn numpy() -> bool {
    let ok = Command::new("python3")
        .args(["-c", "import numpy"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok && std::env::var_os("AUTOTUNE_REQUIRE_PYTHON").is_some() {
        panic!("python3 with numpy is required (AUTOTUNE_REQUIRE_PYTHON is set)");
    }
    if !ok {
        eprintln!("skipped: python3 with numpy is not available");
    }
    ok
}

fn write_records(out: &Path, theta: &str, seed: u64, runs: usize, steps: usize, normalized: bool) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("examples/python/write_records.py");
    let mut cmd = Command::new("python3");
    cmd.arg(&script)
        .args(["--theta", theta, "--seed", &seed.to_string()])
        .args(["--runs", &runs.to_string(), "--steps", &steps.to_string()])
        .arg("--out")
        .arg(out);
    if normalized {
        cmd.arg("--normalized");
    }
    let o = cmd.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Raw e, P, ν, S and the NEES, NIS, e²/P and ν/√S numpy computed from them give the
/// same statistics to rounding (1e-9 relative: numpy inverts, autotune factors).
#[test]
fn precomputed_nees_and_nis_give_the_numbers_of_raw_records() {
    if !numpy() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let theta = "q_accel_x=0.3,q_accel_y=0.2,r_pos_x=1.5,r_pos_y=3";
    let raw = dir.path().join("raw.npz");
    let norm = dir.path().join("norm.npz");
    write_records(&raw, theta, 9, 64, 50, false);
    write_records(&norm, theta, 9, 64, 50, true);
    let (c1, a) = check_json(&[&raw], &[]);
    let (c2, b) = check_json(&[&norm], &[]);
    assert_eq!(c1, c2);
    for stat in ["nees", "nis"] {
        let (x, y) = (per_step(&a, stat), per_step(&b, stat));
        for (u, v) in x.iter().zip(&y) {
            let (u, v) = (u.unwrap(), v.unwrap());
            assert!((u - v).abs() <= 1e-9 * u.abs(), "{stat}: {u} vs {v}");
        }
        let (u, v) = (
            a["report"][stat]["time_average"].as_f64().unwrap(),
            b["report"][stat]["time_average"].as_f64().unwrap(),
        );
        assert!((u - v).abs() <= 1e-9 * u, "{stat} time average: {u} vs {v}");
    }
    for list in ["state_components", "measurement_components"] {
        let (x, y) = (&a["report"][list], &b["report"][list]);
        assert_eq!(x.as_array().unwrap().len(), y.as_array().unwrap().len());
        for (u, v) in x.as_array().unwrap().iter().zip(y.as_array().unwrap()) {
            let (u, v) = (u["value"].as_f64().unwrap(), v["value"].as_f64().unwrap());
            assert!((u - v).abs() <= 1e-9 * u, "{list}: {u} vs {v}");
        }
    }
    assert_eq!(a["report"]["verdict"], b["report"]["verdict"]);
}

/// Records of the Python example at θ against `autotune check problems/cv2d.toml` at the
/// same θ: two independent Monte Carlo estimates of the same filter (other random
/// streams), so their time averages differ by Monte Carlo noise only. Each average's
/// standard deviation is read off its gate interval; the difference must lie within 4.5
/// combined standard deviations (two-sided 7e-6 for each of the 6 comparisons), and the
/// verdicts must agree at the truth (consistent) and at a wrong θ (both inconsistent).
#[test]
fn python_records_agree_with_the_built_in_problem_to_monte_carlo_precision() {
    if !numpy() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let problem = Path::new(env!("CARGO_MANIFEST_DIR")).join("problems/cv2d.toml");
    for (theta, sets) in [
        (
            "q_accel_x=0.5,q_accel_y=0.1,r_pos_x=1,r_pos_y=4",
            ["q_accel_x=0.5", "q_accel_y=0.1", "r_pos_x=1", "r_pos_y=4"],
        ),
        (
            "q_accel_x=0.3,q_accel_y=0.1,r_pos_x=1,r_pos_y=2.5",
            ["q_accel_x=0.3", "q_accel_y=0.1", "r_pos_x=1", "r_pos_y=2.5"],
        ),
        (
            "q_accel_x=0.5,q_accel_y=0.2,r_pos_x=1.5,r_pos_y=4",
            ["q_accel_x=0.5", "q_accel_y=0.2", "r_pos_x=1.5", "r_pos_y=4"],
        ),
    ] {
        let rec = dir.path().join("cv2d.npz");
        write_records(&rec, theta, 11, 200, 200, false);
        let (code_rec, a) = check_json(&[&rec], &[]);
        let mut args = vec!["check", problem.to_str().unwrap(), "--json", "--seed", "11"];
        for s in &sets {
            args.extend(["--set", s]);
        }
        let (code_prob, stdout, stderr) = autotune(&args);
        let b: Value = serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{e}: {stderr}"));
        assert_eq!(
            code_rec, code_prob,
            "θ = {theta}: verdicts {} vs {}",
            a["report"]["verdict"], b["report"]["verdict"]
        );
        for stat in ["nees", "nis"] {
            let sd = |v: &Value| {
                let i = &v["report"][stat]["interval"];
                let (lo, hi) = (i["lower"].as_f64().unwrap(), i["upper"].as_f64().unwrap());
                let z = autotune::internals::stats::normal_two_sided_quantile(
                    v["report"]["statistic_alpha"].as_f64().unwrap(),
                );
                (hi - lo) / (2.0 * z)
            };
            let (x, y) = (
                a["report"][stat]["time_average"].as_f64().unwrap(),
                b["report"][stat]["time_average"].as_f64().unwrap(),
            );
            let tol = 4.5 * (sd(&a).powi(2) + sd(&b).powi(2)).sqrt();
            assert!(
                (x - y).abs() <= tol,
                "θ = {theta}, {stat}: records {x} vs problem {y} (tolerance {tol})"
            );
        }
    }
}

/// Found by `tests/fuzz/loaders.rs`: inputs that aborted on an allocation, hung, or printed a
/// multi-line error. Each is now exit 2 and one line naming the file and where.
#[test]
fn absurd_sizes_and_headers_are_one_line_errors() {
    assert_eq!(
        autotune::internals::records::MAX_STEPS,
        autotune::internals::montecarlo::MAX_STEPS
    );
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let head = "run,step,e_1,P_1_1\n";
    let cases: Vec<(&str, String, &[&str])> = vec![
        (
            "step.csv",
            format!("{head}0,1,1,1\n0,1000000000000,1,1\n"),
            &["step.csv:3", "step", "above the limit of 1000000 steps"],
        ),
        (
            "step.jsonl",
            "{\"run\":0,\"step\":18446744073709551615,\"e\":[1],\"P\":[[1]]}\n".into(),
            &["step.jsonl:1", "above the limit of 1000000 steps"],
        ),
        (
            "index.csv",
            "run,step,e_1,e_99999999999,P_1_1\n0,1,1,1,1\n".into(),
            &["index.csv:1", "column e_2 missing"],
        ),
        (
            "matrix.csv",
            "run,step,e_1,P_1_1,P_9999999999_99999999999\n0,1,1,1,1\n".into(),
            &["matrix.csv:1", "column P_1_2 missing"],
        ),
        (
            "dof.csv",
            "run,step,nees,nees_dof\n0,1,1,18446744073709551616\n".into(),
            &[
                "dof.csv:2",
                "nees_dof is 1.8446744073709552e19, not a whole number in [1, 1000000]",
            ],
        ),
        (
            "tiny.csv",
            "run,step,nis,nis_dof\n0,1,1,1e-300\n".into(),
            &[
                "tiny.csv:2",
                "nis_dof is 1e-300,",
                "not a whole number in [1, 1000000]",
            ],
        ),
        (
            "quoted.csv",
            format!("{head}0,1,1,\"1\n2\"\n"),
            &["quoted.csv:2", "P_1_1: '1\\n2' is not a number"],
        ),
        (
            "empty.jsonl",
            "{\"run\":0,\"step\":1,\"e\":[],\"P\":[]}\n".into(),
            &["empty.jsonl", "has shape [0", "no entries"],
        ),
    ];
    for (name, text, expect) in cases {
        let path = d.join(name);
        std::fs::write(&path, text).unwrap();
        let (code, stdout, stderr) = autotune(&["check", "--records", path.to_str().unwrap()]);
        assert_eq!(code, Some(2), "{name}: {stdout}{stderr}");
        assert_eq!(stderr.lines().count(), 1, "{name}: {stderr}");
        for e in expect {
            assert!(stderr.contains(e), "{name}: expected '{e}' in {stderr}");
        }
    }
    // NumPy: a shape whose element count wraps a u64, a zero-length axis that would let
    // any number of runs be claimed, and a header the Python-literal parser refuses (its
    // error is a drawing over several lines).
    let npy = |name: &str, header: &str, data: &[u8]| -> PathBuf {
        let mut h = header.to_string();
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
        bytes.extend((h.len() as u16).to_le_bytes());
        bytes.extend(h.as_bytes());
        bytes.extend(data);
        let sub = d.join(name);
        std::fs::create_dir_all(&sub).unwrap();
        let p = sub.join("e.npy");
        std::fs::write(&p, bytes).unwrap();
        p
    };
    let p_file = d.join("P.npy");
    write_npy(&p_file, &[3, 4, 1, 1], &[1.0; 12]);
    let cases: Vec<(PathBuf, &[&str])> = vec![
        (
            npy(
                "wrap",
                "{'descr': '<f8', 'fortran_order': False, 'shape': (4294967296, 4294967296, 1), }",
                &[0; 8],
            ),
            &["e.npy", "array e", "above the limit"],
        ),
        (
            npy(
                "huge",
                "{'descr': '<f8', 'fortran_order': False, 'shape': (3, 4, 100000000), }",
                &[0; 8],
            ),
            &["array e", "truncated"],
        ),
        (
            npy(
                "zero",
                "{'descr': '<f8', 'fortran_order': True, 'shape': (1000000000000, 4, 0), }",
                &[],
            ),
            &["zero/e.npy", "has shape [0", "no entries"],
        ),
        (
            npy(
                "syntax",
                "{'descr': '<f8', 'fortran_order': Falsx, 'shape': (3, 4, 1), }",
                &[0; 96],
            ),
            &["e.npy", "not a .npy file", "expected value"],
        ),
    ];
    let own_p = d.join("zero/P.npy");
    let mut h =
        "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 4, 0, 0), }".to_string();
    while !(10 + h.len() + 1).is_multiple_of(64) {
        h.push(' ');
    }
    h.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((h.len() as u16).to_le_bytes());
    bytes.extend(h.as_bytes());
    std::fs::write(&own_p, bytes).unwrap();
    for (path, expect) in cases {
        let p = path.with_file_name("P.npy");
        let p = if p.exists() { p } else { p_file.clone() };
        let (code, stdout, stderr) = autotune(&[
            "check",
            "--records",
            path.to_str().unwrap(),
            p.to_str().unwrap(),
        ]);
        assert_eq!(code, Some(2), "{}: {stdout}{stderr}", path.display());
        assert_eq!(stderr.lines().count(), 1, "{}: {stderr}", path.display());
        for e in expect {
            assert!(stderr.contains(e), "expected '{e}' in {stderr}");
        }
    }
}

/// Issue 39: records of two sensors that take turns (`lidar`, two components, at odd steps;
/// `radar`, one, at even ones), 20 runs of 200 steps. Each sensor's own innovation sequence
/// is a moving average `(w_i + θ w_{i−1}) · √(v / (1 + θ²))` of white noise (lag-1
/// correlation `θ / (1 + θ²)` between a sensor's successive readings, variance `v` relative
/// to S): what a filter with a wrong Q leaves behind.
fn write_alternating(path: &Path, theta: f64, v: f64, seed: u64) {
    use autotune::SimRng;
    use rand::{RngExt, SeedableRng};
    use rand_distr::StandardNormal;
    let mut rng = SimRng::seed_from_u64(seed);
    let scale = (v / (1.0 + theta * theta)).sqrt();
    let mut text = String::from(
        "run,step,nu_lidar_1,nu_lidar_2,S_lidar_1_1,S_lidar_1_2,S_lidar_2_2,nu_radar_1,S_radar_1_1\n",
    );
    for run in 0..20 {
        let mut w: [f64; 3] = std::array::from_fn(|_| rng.sample(StandardNormal));
        let mut ma = |c: usize, rng: &mut SimRng| {
            let next: f64 = rng.sample(StandardNormal);
            let u = (next + theta * w[c]) * scale;
            w[c] = next;
            u
        };
        for k in 1..=200 {
            if k % 2 == 1 {
                let (a, b) = (ma(0, &mut rng), ma(1, &mut rng));
                text += &format!("{run},{k},{},{},4,0,4,,\n", 2.0 * a, 2.0 * b);
            } else {
                text += &format!("{run},{k},,,,,,{},9\n", 3.0 * ma(2, &mut rng));
            }
        }
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn sensors_that_take_turns_are_paired_and_diagnosed_as_nis_pairs_and_diagnoses_them() {
    // Each reading pairs with its own sensor's previous one, not with the step before
    // (which the other sensor measured): 99 pairs per run at lag 1 for every component, the
    // same ρ as `autotune nis` computes from the same innovations (to rounding: the two sum
    // the same products), and the same Q-vs-R finding. θ = −0.6 with v = 0.8 (too much Q:
    // successive innovations anticorrelated, NIS low) must read "decrease Q"; θ = +0.6 with
    // v = 1.2 (too little Q) "increase Q". At 1980 pairs ρ₁'s standard error is 0.022,
    // against ±0.44. (`nis` sets outliers aside, beyond NIS's 10⁻⁵ tail, and pairs around
    // them; at v ≤ 1.2 a sensor's 2000 updates expect at most 0.14 of them, and these have
    // none.)
    let dir = tempfile::tempdir().unwrap();
    for (theta, v, action) in [(-0.6, 0.8, "decrease Q"), (0.6, 1.2, "increase Q")] {
        let path = dir.path().join(format!("alternating_{theta}.csv"));
        write_alternating(&path, theta, v, 39);
        let (_, check) = check_json(&[&path], &[]);
        let (_, nis, stderr) = autotune(&["nis", "--json", path.to_str().unwrap()]);
        let nis: Value = serde_json::from_str(&nis).unwrap_or_else(|e| panic!("{e}: {stderr}"));
        let report = &check["report"];
        for s in nis["sensors"].as_array().unwrap() {
            assert_eq!(s["outliers"], 0, "{}", s["name"]);
        }
        let rho = |white: &Value, component: &str, lag: u64| {
            white
                .as_array()
                .unwrap()
                .iter()
                .find(|w| w["component"] == component && w["lag"] == lag)
                .map(|w| (w["rho"].as_f64().unwrap(), w["pairs"].as_f64().unwrap()))
                .unwrap_or_else(|| panic!("{component} lag {lag} in {white}"))
        };
        for (sensor, component, name) in [
            (0, "lidar_1", "lidar_1"),
            (0, "lidar_2", "lidar_2"),
            (1, "radar_1", "radar_1"),
        ] {
            for lag in 1..=3 {
                let (r_check, pairs) = rho(&report["whiteness"], name, lag);
                let (r_nis, nis_pairs) = rho(&nis["sensors"][sensor]["whiteness"], component, lag);
                assert_eq!(pairs, 20.0 * (100 - lag) as f64, "{name} lag {lag}: pairs");
                assert_eq!(pairs, nis_pairs, "{name} lag {lag}");
                assert!(
                    (r_check - r_nis).abs() < 1e-12,
                    "{name} lag {lag}: {r_check} vs {r_nis}"
                );
            }
            let want = theta / (1.0 + theta * theta);
            let (r1, _) = rho(&report["whiteness"], name, 1);
            assert!(
                (r1 - want).abs() < 0.07,
                "{name}: ρ₁ {r1}, the process's {want}"
            );
        }
        let findings = report["diagnosis"]["findings"].as_array().unwrap();
        assert_eq!(findings.len(), 3, "{findings:?}");
        for f in findings {
            assert_eq!(f["action"], action, "check: {f}");
        }
        for s in nis["sensors"].as_array().unwrap() {
            assert_eq!(s["finding"]["action"], action, "nis: {}", s["finding"]);
        }
        assert_eq!(report["diagnosis"]["suspect"], "q");
        assert_eq!(nis["suspect"], "q");
    }
}

/// One run of `steps` steps of a 2-state filter whose error is a stationary AR(1) vector
/// (`e_k = 0.8 e_{k−1} + 0.6 w_k`, unit variance) and whose P is `p · I`, as a records CSV
/// of errors and covariances alone (no innovations, no error map).
fn write_recording(path: &Path, runs: usize, steps: usize, p: f64, seed: u64) {
    use autotune::SimRng;
    use rand::{RngExt, SeedableRng};
    use rand_distr::StandardNormal;
    let mut rng = SimRng::seed_from_u64(seed);
    let mut text = String::from("run,step,e_1,e_2,P_1_1,P_1_2,P_2_2\n");
    for run in 0..runs {
        let mut e: [f64; 2] = std::array::from_fn(|_| rng.sample(StandardNormal));
        for k in 1..=steps {
            for x in e.iter_mut() {
                *x = 0.8 * *x + 0.6 * rng.sample::<f64, _>(StandardNormal);
            }
            text += &format!("{run},{k},{},{},{p},0,{p}\n", e[0], e[1]);
        }
    }
    std::fs::write(path, text).unwrap();
}

#[test]
fn one_recording_with_truth_gets_a_nees_verdict_from_batch_means() {
    // Issue 39: a single recording of a filter that supplies no error map has no per-run
    // spread; its ANEES interval comes from batch means over its steps (the rates over
    // many recordings are src/stats/interval.rs's tests). Here: a consistent filter passes
    // on 500 steps, one whose P is half the truth fails as overconfident, a recording of 30
    // steps gets no interval and says why, and errors without innovations (ANIS has no
    // data) are judged on ANEES alone, for one run as for twenty.
    let dir = tempfile::tempdir().unwrap();
    let file = |name: &str| dir.path().join(name);
    write_recording(&file("one.csv"), 1, 500, 1.0, 3);
    write_recording(&file("half.csv"), 1, 500, 0.5, 3);
    write_recording(&file("short.csv"), 1, 30, 1.0, 3);
    write_recording(&file("twenty.csv"), 20, 100, 1.0, 3);
    let (code, one) = check_json(&[&file("one.csv")], &[]);
    let nees = &one["report"]["nees"];
    assert_eq!(one["report"]["verdict"], "consistent", "{nees}");
    assert_eq!(code, Some(0));
    let blocks = nees["batch_spread_batches"].as_u64().expect("batch means");
    assert!((8..=32).contains(&blocks), "{blocks}");
    let (lo, hi) = (
        nees["interval"]["lower"].as_f64().unwrap(),
        nees["interval"]["upper"].as_f64().unwrap(),
    );
    // Around the target 2, no wider than ±40% (the ANEES of 500 steps correlated over about
    // 4.6 steps has a standard deviation near 0.19; the t quantile of the blocks and the
    // spread's own noise widen the interval to about ±36% here).
    assert!(lo < 2.0 && 2.0 < hi && hi - lo < 1.6, "[{lo}, {hi}]");
    let (code, half) = check_json(&[&file("half.csv")], &[]);
    assert_eq!(half["report"]["verdict"], "overconfident");
    assert_eq!(code, Some(1));
    let (code, stdout, _) = autotune(&["check", "--records", file("short.csv").to_str().unwrap()]);
    assert_eq!(code, Some(1));
    assert!(
        stdout.contains("none (see note)") && !stdout.contains("NaN"),
        "{stdout}"
    );
    assert!(
        stdout.contains("a recording of at least 40 steps, or a second recording"),
        "{stdout}"
    );
    assert!(stdout.contains("verdict: inconclusive"), "{stdout}");
    let (code, twenty) = check_json(&[&file("twenty.csv")], &[]);
    assert_eq!(twenty["report"]["verdict"], "consistent");
    assert_eq!(code, Some(0));
    assert!(twenty["report"]["nees"]["batch_spread_batches"].is_null());
}

//! A worker that replays (issue 39): a worker's filter run over a recorded measurement
//! record that autotune names (`"replay": path`), answered with `"replays": true`; and a
//! worker whose runs are recordings it replays, which says so and is then not held to the
//! seed contract.

use autotune::Structure;
use std::path::{Path, PathBuf};

use crate::common::{self, autotune};
use crate::records::numpy;
use autotune::internals::estimate::{MeasurementRecord, ReplayExperiment, ml, simulate};
use autotune::internals::experiment::Experiment;
use autotune::internals::external::WorkerReplay;
use autotune::internals::problem::Problem;

fn example(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("examples/python")
        .join(name)
}

/// `data` as a measurement CSV (`run,step,z_1,…`, an empty cell where not measured).
fn write_csv(path: &Path, data: &MeasurementRecord) {
    let mut text = String::from("run,step");
    for j in 1..=data.dim {
        text += &format!(",z_{j}");
    }
    text.push('\n');
    for (i, seq) in data.sequences.iter().enumerate() {
        for (k, z) in seq.z.chunks(data.dim).enumerate() {
            text += &format!("{i},{}", k + 1);
            for v in z {
                if v.is_finite() {
                    text += &format!(",{v:?}");
                } else {
                    text.push(',');
                }
            }
            text.push('\n');
        }
    }
    std::fs::write(path, text).unwrap();
}

/// examples/python/cv2d_replay.py, cv2d's Kalman filter written apart in NumPy, replayed
/// over a two-sequence record with a gap: its `−log L` at three θ equals autotune's exact
/// likelihood of the same filter to 1e-9, its NIS and whiteness sums equal the built-in
/// record path's, and the maximum-likelihood search through it gives the built-in estimate
/// to 1e-6 and its standard errors to 1e-5. Every number the search sees being the same to 1e-9, the
/// interval coverage measured on the built-in filters (tests/estimate/replay.rs) holds for
/// a worker that replays.
#[test]
fn a_python_worker_replays_a_record_as_the_built_in_filter_does() {
    if !numpy() {
        return;
    }
    let cv2d = common::load("cv2d");
    let lin = cv2d.linear().expect("cv2d is linear");
    let mut data = simulate(&lin.truth, 2, 2, 120, 5).measurements;
    data.sequences[1].z[40..42].fill(f64::NAN);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("z.csv");
    write_csv(&path, &data);
    let p = Problem::load(&example("cv2d_replay.toml")).expect("the example loads");
    let w = p.worker().expect("an [external] problem");
    let replay = WorkerReplay::new(w, &path, 2, 120).expect("a record");
    let truth = common::truth_values(&cv2d);
    let start = cv2d.params().values();
    for theta in [
        truth.clone(),
        truth.iter().map(|v| v * 1.7).collect(),
        start.clone(),
    ] {
        let worker = replay
            .neg_log_likelihood(&theta)
            .unwrap()
            .expect("raw records");
        let exact = lin.filter_at(&theta).neg_log_likelihood(&data).unwrap();
        assert!(
            (worker - exact).abs() <= 1e-9 * exact.abs(),
            "θ {theta:?}: worker {worker}, exact {exact}"
        );
    }
    let built_in = ReplayExperiment::new(lin, data.clone()).unwrap();
    let mc = built_in.mc().with_lags(3).unwrap();
    let a = replay.monte_carlo(&truth, &mc).unwrap();
    let b = built_in.monte_carlo(&truth, &mc).unwrap();
    for (what, x, y) in [
        ("nis_sum", a.nis_sum(), b.nis_sum()),
        ("white_ab", a.white_ab(), b.white_ab()),
        ("white_pairs", a.white_pairs(), b.white_pairs()),
    ] {
        assert_eq!(x.len(), y.len(), "{what}");
        for (u, v) in x.iter().zip(y) {
            assert!(
                (u - v).abs() <= 1e-9 * u.abs().max(1.0),
                "{what}: {u} vs {v}"
            );
        }
    }
    let fixed = [false; 4];
    let nll = |t: &[f64]| replay.neg_log_likelihood(t).ok().flatten();
    let through = ml::estimate_by(&nll, data.values(), &start, &fixed, 200).unwrap();
    let build = |t: &[f64]| lin.filter_at(t);
    let own = ml::estimate(&build, &data, &start, &fixed, 200).unwrap();
    assert!(through.converged && own.converged);
    for i in 0..4 {
        let (x, y) = (through.theta[i], own.theta[i]);
        assert!((x - y).abs() <= 1e-6 * y, "θ{i}: {x} vs {y}");
        // Standard errors are second differences of −log L, which magnify its last digits
        // (measured: 3e-6 apart).
        let (x, y) = (through.std_errors[i].unwrap(), own.std_errors[i].unwrap());
        assert!((x - y).abs() <= 1e-5 * y, "se{i}: {x} vs {y}");
    }
    // The commands: `check --measurements` through the worker prints the built-in ANIS.
    let z = path.to_str().unwrap();
    let (code, out, err) = autotune(&[
        "check",
        example("cv2d_replay.toml").to_str().unwrap(),
        "--measurements",
        z,
    ]);
    let (code_b, out_b, _) = autotune(&[
        "check",
        common::problem_path("cv2d").to_str().unwrap(),
        "--measurements",
        z,
    ]);
    assert_eq!(code, code_b, "{out}{err}");
    let anis = |o: &str| o.lines().find(|l| l.contains("ANIS")).map(str::to_string);
    assert_eq!(anis(&out), anis(&out_b), "{out}\n{out_b}");
}

/// A worker that answers a replay request without `"replays": true` (it simulated instead)
/// stops the command in one line that says what a replaying worker answers, exit 2.
#[test]
fn a_worker_that_does_not_say_it_replays_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("w.py"),
        "import json, sys\nfor line in sys.stdin:\n    r = json.loads(line)\n    print(json.dumps({'id': r['id'], 'done': True}), flush=True)\n",
    )
    .unwrap();
    let problem = dir.path().join("p.toml");
    std::fs::write(
        &problem,
        "name = \"p\"\n[montecarlo]\nruns = 1\nsteps = 3\n[external]\ncommand = [\"python3\", \"w.py\"]\nsensors = { pos = [\"x\"] }\nworkers = 1\n[params.r]\nvalue = 1.0\n",
    )
    .unwrap();
    let z = dir.path().join("z.csv");
    std::fs::write(&z, "step,z_1\n1,0.5\n2,-0.1\n3,0.2\n").unwrap();
    let (code, out, err) = autotune(&[
        "check",
        problem.to_str().unwrap(),
        "--measurements",
        z.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(2), "{out}{err}");
    assert_eq!(err.lines().count(), 1, "{err}");
    assert!(err.contains("\"replays\": true"), "{err}");
}

/// A worker whose four runs are the same recording, replayed: without `"replays": true`
/// the seed contract refuses it ("all the same"); with it, `check` judges the four runs
/// and `tune` says the record was judged once, on no fresh seeds.
#[test]
fn a_worker_that_replays_its_recordings_is_not_held_to_the_seed_contract() {
    let dir = tempfile::tempdir().unwrap();
    let worker = |replays: bool| {
        format!(
            "import json, sys\nfor line in sys.stdin:\n    r = json.loads(line)\n    a, b = r['runs']\n    for i in range(a, b):\n        for k in range(1, r['steps'] + 1):\n            u = ((k * 7919) % 200 - 100) / 60.0 * r['theta']['s'] ** -0.5\n            print(json.dumps({{'run': i, 'step': k, 'nis_pos': u * u, 'nis_dof_pos': 1, 'u_pos': [u]}}))\n    print(json.dumps({{'id': r['id'], 'done': True{}}}), flush=True)\n",
            if replays { ", 'replays': True" } else { "" }
        )
    };
    let problem = dir.path().join("p.toml");
    std::fs::write(
        &problem,
        "name = \"p\"\n[montecarlo]\nruns = 4\nsteps = 50\n[external]\ncommand = [\"python3\", \"w.py\"]\nsensors = { pos = [\"x\"] }\nworkers = 1\n[params.s]\nvalue = 1.0\n",
    )
    .unwrap();
    let p = problem.to_str().unwrap();
    std::fs::write(dir.path().join("w.py"), worker(false)).unwrap();
    let (code, out, err) = autotune(&["check", p]);
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(err.contains("seed"), "{err}");
    std::fs::write(dir.path().join("w.py"), worker(true)).unwrap();
    let (code, out, err) = autotune(&["check", p]);
    assert!(matches!(code, Some(0 | 1)), "{out}{err}");
    assert!(out.contains("N = 4 runs"), "{out}");
    let tuned = dir.path().join("t.toml");
    let (code, out, err) = autotune(&["tune", p, "--out", tuned.to_str().unwrap()]);
    assert!(matches!(code, Some(0 | 1)), "{out}{err}");
    assert!(
        out.contains("no fresh seeds") && !out.contains("fresh seeds pass"),
        "{out}"
    );
}

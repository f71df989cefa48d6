//! Issue 26: a check in shards merged, and check and tune across MPI ranks, give the
//! one-process JSON, reports and tuned configs byte for byte, on a linear problem
//! (problems/cv2d.toml), a catalog one (problems/ctrv.toml) and external workers (the
//! Python example examples/python/cv2d_numpy.toml, the scripted test worker); shards of
//! different problems or settings refuse to merge; a failing worker or a killed rank ends an
//! MPI job with exit 2, naming the rank, within the worker's timeout.
//!
//! The MPI cases run the `autotune` built with the `mpi` feature, given in
//! AUTOTUNE_MPI_BIN, under `mpirun` (with `--oversubscribe`: this machine has 2 cores); they
//! are skipped without it, and required where AUTOTUNE_REQUIRE_MPI is set, as in CI.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use assert_cmd::cargo::CommandCargoExt;

mod common;

fn repo(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join(path)
        .display()
        .to_string()
}

struct Out {
    code: Option<i32>,
    stdout: String,
    stderr: String,
}

fn output(cmd: &mut Command) -> Out {
    let out = cmd.output().unwrap();
    Out {
        code: out.status.code(),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    }
}

/// The default `autotune` in `dir`.
fn one(dir: &Path, args: &[&str]) -> Out {
    output(
        Command::cargo_bin("autotune")
            .unwrap()
            .args(args)
            .current_dir(dir),
    )
}

/// The MPI build of autotune, if given.
fn mpi_bin() -> Option<PathBuf> {
    match std::env::var_os("AUTOTUNE_MPI_BIN") {
        Some(p) => Some(PathBuf::from(p)),
        None if std::env::var_os("AUTOTUNE_REQUIRE_MPI").is_some() => {
            panic!("AUTOTUNE_REQUIRE_MPI is set but AUTOTUNE_MPI_BIN is not")
        }
        None => {
            eprintln!("skipped: AUTOTUNE_MPI_BIN (autotune built with --features mpi) not set");
            None
        }
    }
}

/// `mpirun -np ranks --oversubscribe bin args` in `dir`.
fn mpirun(bin: &Path, ranks: usize, dir: &Path, args: &[&str], env: &[(&str, &str)]) -> Command {
    let mut cmd = Command::new("mpirun");
    cmd.args(["-np", &ranks.to_string(), "--oversubscribe"])
        .arg(bin)
        .args(args)
        .current_dir(dir)
        // Open MPI refuses root without these (CI runs as root).
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1");
    for (k, v) in env {
        cmd.env(k, v);
    }
    cmd
}

/// Every file under `dir`, by relative path, with its bytes.
fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    if !dir.exists() {
        return out;
    }
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.push((
                    p.strip_prefix(dir).unwrap().to_path_buf(),
                    std::fs::read(&p).unwrap(),
                ));
            }
        }
    }
    out.sort();
    out
}

/// What a check leaves: exit code, JSON on stdout, the report directory and the JUnit file.
#[derive(Debug, PartialEq)]
struct Checked {
    code: Option<i32>,
    json: String,
    report: Vec<(PathBuf, Vec<u8>)>,
    junit: Vec<u8>,
}

fn outputs_of(dir: &Path, out: &Out) -> Checked {
    Checked {
        code: out.code,
        json: out.stdout.clone(),
        report: files(&dir.join("report")),
        junit: std::fs::read(dir.join("junit.xml")).unwrap_or_default(),
    }
}

const OUTPUTS: [&str; 5] = ["--json", "--report", "report", "--junit", "junit.xml"];

/// `check problem extra…` in one process, and as three shards merged: the same outputs.
fn check_one_and_shards(problem: &str, extra: &[&str]) -> Checked {
    let whole = tempfile::tempdir().unwrap();
    let mut args = vec!["check", problem];
    args.extend(extra);
    let single = one(whole.path(), &[&args[..], &OUTPUTS].concat());
    assert!(
        matches!(single.code, Some(0 | 1)),
        "{problem}: {}",
        single.stderr
    );
    let single = outputs_of(whole.path(), &single);
    assert!(single.json.contains("\"verdict\""), "{}", single.json);

    let sharded = tempfile::tempdir().unwrap();
    for i in 0..3 {
        let shard = format!("{i}/3");
        let out = format!("shard{i}.json");
        let r = one(
            sharded.path(),
            &[&args[..], &["--shard", &shard, "--sums-out", &out]].concat(),
        );
        assert_eq!(r.code, Some(0), "{problem} shard {i}: {}", r.stderr);
        assert!(r.stdout.contains(&format!("shard {i}/3")), "{}", r.stdout);
    }
    // Any order.
    let merge = [
        &["merge", "shard2.json", "shard0.json", "shard1.json"][..],
        &OUTPUTS,
    ]
    .concat();
    let merged = one(sharded.path(), &merge);
    assert_eq!(
        outputs_of(sharded.path(), &merged),
        single,
        "{problem}: 3 shards merged differ from one process: {}",
        merged.stderr
    );
    single
}

/// `check` under `mpirun -np 2` and `-np 3`: the one-process outputs.
fn check_on_ranks(problem: &str, extra: &[&str], single: &Checked) {
    let Some(bin) = mpi_bin() else { return };
    for ranks in [2, 3] {
        let dir = tempfile::tempdir().unwrap();
        let args = [&["check", problem][..], extra, &OUTPUTS].concat();
        let out = output(&mut mpirun(&bin, ranks, dir.path(), &args, &[]));
        assert_eq!(
            &outputs_of(dir.path(), &out),
            single,
            "{problem} on {ranks} ranks: {}",
            out.stderr
        );
    }
}

#[test]
fn a_linear_check_is_the_same_in_shards_and_on_ranks() {
    let p = repo("problems/cv2d.toml");
    let extra = ["--runs", "300"];
    let single = check_one_and_shards(&p, &extra);
    check_on_ranks(&p, &extra, &single);
}

#[test]
fn a_catalog_check_is_the_same_in_shards_and_on_ranks() {
    let p = repo("problems/ctrv.toml");
    let extra = ["--runs", "200"];
    let single = check_one_and_shards(&p, &extra);
    check_on_ranks(&p, &extra, &single);
}

/// Whether `python3` runs and imports `modules` (the scripted worker needs none, the
/// Python example NumPy); required where AUTOTUNE_REQUIRE_PYTHON is set, as in CI.
fn python(modules: &str) -> bool {
    let ok = Command::new("python3")
        .args(["-c", &format!("import sys{modules}")])
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !ok && std::env::var_os("AUTOTUNE_REQUIRE_PYTHON").is_some() {
        panic!("python3 (importing sys{modules}) is required (AUTOTUNE_REQUIRE_PYTHON is set)");
    }
    if !ok {
        eprintln!("skipped: python3 (importing sys{modules}) is not available");
    }
    ok
}

fn numpy() -> bool {
    python(", numpy")
}

fn common_python() -> bool {
    python("")
}

#[test]
fn a_python_worker_check_is_the_same_in_shards_and_on_ranks() {
    if !numpy() {
        return;
    }
    let p = repo("examples/python/cv2d_numpy.toml");
    let extra = ["--runs", "200", "--steps", "50"];
    let single = check_one_and_shards(&p, &extra);
    check_on_ranks(&p, &extra, &single);
}

/// The scripted test worker's problem (a scalar random walk) in `mode`, written into `dir`.
fn walk(dir: &Path, mode: &str, runs: usize) -> PathBuf {
    let text = format!(
        r#"name = "walk"
state_names = ["x"]

[montecarlo]
runs = {runs}
steps = 20
seed = 5

[external]
command = ["python3", "{script}", "{mode}"]
sensors = {{ z = ["pos"] }}
workers = 1
timeout = 3
truth = {{ q = 0.5, r = 2.0 }}

[tune]
search_runs = 128
refine_runs = 256
confirm_seeds = 4
max_evals = 300

[params.q]
value = 0.2
lower = 0.01
upper = 100.0

[params.r]
value = 5.0
lower = 0.01
upper = 100.0
"#,
        script = repo("tests/data/workers/fake_worker.py")
    );
    let path = dir.join(format!("walk_{mode}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

/// What a tune leaves: exit code, JSON, the report directory, and in place of the JUnit
/// file the tuned configs' names and bytes.
fn tune_outputs(dir: &Path, out: &Out) -> Checked {
    Checked {
        code: out.code,
        json: out.stdout.clone(),
        report: files(&dir.join("report")),
        junit: files(&dir.join("tuned"))
            .into_iter()
            .flat_map(|(path, bytes)| [path.display().to_string().into_bytes(), bytes])
            .flatten()
            .collect(),
    }
}

/// `tune problem` in one process (on 1 thread, and on 2) and under `mpirun -np 1`, `-np 2`
/// and `-np 3`: the same JSON, report and tuned config.
fn tune_one_and_ranks(problem: &str, name: &str) {
    let args = ["tune", problem, "--json", "--report", "report"];
    let on_threads = |threads: &str| {
        let dir = tempfile::tempdir().unwrap();
        let out = output(
            Command::cargo_bin("autotune")
                .unwrap()
                .args(args)
                .current_dir(dir.path())
                .env("RAYON_NUM_THREADS", threads),
        );
        assert!(matches!(out.code, Some(0 | 1)), "{name}: {}", out.stderr);
        tune_outputs(dir.path(), &out)
    };
    let single = on_threads("1");
    assert!(!single.junit.is_empty(), "{name}: a tuned config");
    assert_eq!(on_threads("2"), single, "{name} tuned on 2 threads");
    let Some(bin) = mpi_bin() else { return };
    for ranks in [1, 2, 3] {
        let dir = tempfile::tempdir().unwrap();
        let out = output(&mut mpirun(&bin, ranks, dir.path(), &args, &[]));
        assert_eq!(
            tune_outputs(dir.path(), &out),
            single,
            "{name} tuned on {ranks} ranks: {}",
            out.stderr
        );
    }
}

#[test]
fn linear_catalog_and_worker_tunes_are_the_same_on_ranks() {
    tune_one_and_ranks(&repo("problems/cv2d.toml"), "cv2d");
    tune_one_and_ranks(&repo("problems/ctrv.toml"), "ctrv");
    if common_python() {
        let dir = tempfile::tempdir().unwrap();
        let p = walk(dir.path(), "good", 200);
        tune_one_and_ranks(p.to_str().unwrap(), "walk");
    }
    // The Python example: each rank starts its own NumPy workers.
    if numpy() {
        tune_one_and_ranks(&repo("examples/python/cv2d_numpy.toml"), "cv2d_numpy");
    }
}

/// Shards of `args_a` and `args_b` (three each, in their own directories): the first shard
/// of one with the others of the other refuse to merge, with one line naming `field`.
fn refuses(a: &[&str], b: &[&str], field: &str) {
    let dir = tempfile::tempdir().unwrap();
    for (tag, args) in [("a", a), ("b", b)] {
        for i in 0..3 {
            let shard = format!("{i}/3");
            let out = format!("{tag}{i}.json");
            let r = one(
                dir.path(),
                &[
                    &["check"][..],
                    args,
                    &["--shard", &shard, "--sums-out", &out],
                ]
                .concat(),
            );
            assert_eq!(r.code, Some(0), "{}", r.stderr);
        }
    }
    let r = one(
        dir.path(),
        &["merge", "a0.json", "b1.json", "b2.json", "--json"],
    );
    assert_eq!(r.code, Some(2), "{}", r.stdout);
    assert!(r.stdout.is_empty());
    assert_eq!(r.stderr.lines().count(), 1, "{}", r.stderr);
    assert!(
        r.stderr.contains("b1.json")
            && r.stderr.contains(field)
            && r.stderr.contains("do not merge"),
        "{field}: {}",
        r.stderr
    );
}

#[test]
fn shards_of_other_problems_or_settings_refuse_to_merge() {
    let (cv2d, ctrv) = (repo("problems/cv2d.toml"), repo("problems/ctrv.toml"));
    refuses(
        &[&cv2d, "--runs", "200"],
        &[&ctrv, "--runs", "200"],
        "problem",
    );
    refuses(
        &[&cv2d, "--runs", "200"],
        &[&cv2d, "--runs", "200", "--seed", "9"],
        "seed",
    );
    refuses(&[&cv2d, "--runs", "200"], &[&cv2d, "--runs", "300"], "runs");
    refuses(
        &[&cv2d, "--runs", "200"],
        &[&cv2d, "--runs", "200", "--set", "q_accel_x=0.3"],
        "params",
    );
    refuses(
        &[&cv2d, "--runs", "200"],
        &[&cv2d, "--runs", "200", "--engine", "generic"],
        "engine",
    );
}

#[test]
fn incomplete_doubled_tampered_or_stale_shards_are_one_line_errors() {
    let dir = tempfile::tempdir().unwrap();
    let problem = dir.path().join("cv2d.toml");
    std::fs::copy(repo("problems/cv2d.toml"), &problem).unwrap();
    let p = problem.to_str().unwrap();
    for i in 0..3 {
        let (shard, out) = (format!("{i}/3"), format!("s{i}.json"));
        let r = one(
            dir.path(),
            &[
                "check",
                p,
                "--runs",
                "300",
                "--shard",
                &shard,
                "--sums-out",
                &out,
            ],
        );
        assert_eq!(r.code, Some(0), "{}", r.stderr);
    }
    let fails = |args: &[&str], expect: &str| {
        let r = one(dir.path(), &[&["merge"][..], args].concat());
        assert_eq!(r.code, Some(2), "{args:?}: {}", r.stdout);
        assert_eq!(r.stderr.lines().count(), 1, "{args:?}: {}", r.stderr);
        assert!(
            r.stderr.contains(expect),
            "{args:?}: expected '{expect}' in {}",
            r.stderr
        );
    };
    fails(&["s0.json", "s1.json"], "shard 2/3 is missing");
    fails(
        &["s0.json", "s0.json", "s1.json", "s2.json"],
        "shard 0/3 is also",
    );
    let text = std::fs::read_to_string(dir.path().join("s1.json")).unwrap();
    std::fs::write(
        dir.path().join("v2.json"),
        text.replace("\"version\": 1", "\"version\": 2"),
    )
    .unwrap();
    fails(&["s0.json", "v2.json", "s2.json"], "version 2");
    // A chunk's sums from the other shard's place: the format's own checks refuse it.
    let file: serde_json::Value = serde_json::from_str(&text).unwrap();
    let mut moved = file.clone();
    moved["chunks"][0]["chunk"] = 0.into();
    std::fs::write(dir.path().join("moved.json"), moved.to_string()).unwrap();
    fails(
        &["s0.json", "moved.json", "s2.json"],
        "chunk 0 is not shard 1/3's",
    );
    let mut cut = file.clone();
    let sums = cut["chunks"][0]["sums"].as_str().unwrap().to_string();
    cut["chunks"][0]["sums"] = sums[..sums.len() / 2].into();
    std::fs::write(dir.path().join("cut.json"), cut.to_string()).unwrap();
    fails(&["s0.json", "cut.json", "s2.json"], "chunk 1");
    fails(&["/dev/zero"], "not a regular file");
    // The problem file changed after the shards were computed.
    let mut text = std::fs::read_to_string(&problem).unwrap();
    text.push_str("\n# edited\n");
    std::fs::write(&problem, text).unwrap();
    fails(
        &["s0.json", "s1.json", "s2.json"],
        "changed since the shards were computed",
    );
}

/// Run `autotune check walk` in `mode` on `ranks` ranks with `env`: it ends with exit 2
/// within `within`, one of its lines naming `rank` and containing `expect`.
fn rank_fails(mode: &str, ranks: usize, env: &[(&str, &str)], rank: usize, expect: &str) {
    let Some(bin) = mpi_bin() else { return };
    if !common_python() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = walk(dir.path(), mode, 400);
    let start = Instant::now();
    let out = output(&mut mpirun(
        &bin,
        ranks,
        dir.path(),
        &["check", p.to_str().unwrap()],
        env,
    ));
    assert_eq!(out.code, Some(2), "{mode} {env:?}: {}", out.stderr);
    let said = format!("error: rank {rank} of {ranks}: ");
    assert!(
        out.stderr
            .lines()
            .any(|l| l.starts_with(&said) && l.contains(expect)),
        "{mode} {env:?}: expected '{said}…{expect}' in {}",
        out.stderr
    );
    // The worker's timeout is 3 s; MPI's start and end take about 2 s more.
    assert!(
        start.elapsed() < Duration::from_secs(12),
        "{:?}",
        start.elapsed()
    );
}

#[test]
fn a_failing_worker_on_any_rank_ends_the_job_with_exit_2_naming_the_rank() {
    for rank in [0, 1, 2] {
        let r = rank.to_string();
        let env = [("FAKE_FAIL", "error"), ("FAKE_FAIL_RANK", r.as_str())];
        rank_fails("ranked", 3, &env, rank, "theta out of range");
    }
    let env = [("FAKE_FAIL", "timeout"), ("FAKE_FAIL_RANK", "1")];
    rank_fails("ranked", 2, &env, 1, "no answer within the timeout of 3 s");
}

/// The PID of rank `rank`'s autotune under `mpirun` in `dir` (found by its executable,
/// working directory and environment: other tests run MPI jobs at the same time).
fn rank_pid(bin: &Path, dir: &Path, rank: usize) -> Option<u32> {
    let want = format!("OMPI_COMM_WORLD_RANK={rank}");
    for e in std::fs::read_dir("/proc").ok()? {
        let Ok(e) = e else { continue };
        let Ok(pid) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let exe = std::fs::read_link(e.path().join("exe")).ok();
        let cwd = std::fs::read_link(e.path().join("cwd")).ok();
        if exe.as_deref() != Some(bin) || cwd.as_deref() != Some(dir) {
            continue;
        }
        let env = std::fs::read(e.path().join("environ")).unwrap_or_default();
        if env.split(|&b| b == 0).any(|v| v == want.as_bytes()) {
            return Some(pid);
        }
    }
    None
}

/// A check on 3 ranks whose worker takes 0.5 s a request, `signal` sent to rank `rank`'s
/// process once its workers run: the job ends within a few seconds; returns its output.
fn kill_rank(signal: i32, rank: usize) -> Option<Out> {
    if !common_python() {
        return None;
    }
    let dir = tempfile::tempdir().unwrap();
    let p = walk(dir.path(), "slow", 64 * 30);
    stop_rank(dir.path(), &["check", p.to_str().unwrap()], signal, rank)
}

/// `args` on 3 ranks in `dir`, `signal` sent to rank `rank`'s process 1.5 s after it
/// started: the job ends within a few seconds; returns its output.
fn stop_rank(dir: &Path, args: &[&str], signal: i32, rank: usize) -> Option<Out> {
    let bin = mpi_bin()?.canonicalize().unwrap();
    let here = dir.canonicalize().unwrap();
    let mut cmd = mpirun(&bin, 3, dir, args, &[]);
    common::with_default_signals(&mut cmd);
    let child = cmd
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    let pid = loop {
        if let Some(pid) = rank_pid(&bin, &here, rank) {
            break pid;
        }
        assert!(
            start.elapsed() < Duration::from_secs(20),
            "rank {rank} never started"
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    // Mid-evaluation: the ranks' first requests are out.
    std::thread::sleep(Duration::from_millis(1500));
    unsafe { libc::kill(pid as i32, signal) };
    let killed = Instant::now();
    let out = child.wait_with_output().unwrap();
    assert!(
        killed.elapsed() < Duration::from_secs(10),
        "{:?}",
        killed.elapsed()
    );
    Some(Out {
        code: out.status.code(),
        stdout: String::from_utf8_lossy(&out.stdout).into_owned(),
        stderr: String::from_utf8_lossy(&out.stderr).into_owned(),
    })
}

/// The job ended with exit 2, a line naming rank `rank` of 3 stopped by SIGTERM, and no
/// verdict.
fn stopped_by_sigterm(out: &Out, rank: usize) {
    assert_eq!(out.code, Some(2), "{}", out.stderr);
    let said = format!("error: rank {rank} of 3: stopped by signal 15");
    assert!(
        out.stderr.contains(&said),
        "expected '{said}' in {}",
        out.stderr
    );
    assert!(out.stdout.is_empty(), "no verdict: {}", out.stdout);
}

#[test]
fn a_rank_stopped_mid_evaluation_ends_the_job_with_exit_2_naming_it() {
    for rank in [1, 0] {
        let Some(out) = kill_rank(libc::SIGTERM, rank) else {
            return;
        };
        stopped_by_sigterm(&out, rank);
    }
}

#[test]
fn a_rank_stopped_mid_tune_while_evaluations_are_dealt_by_runs_ends_the_job_with_exit_2() {
    // ins_gnss's evaluations are one to four chunks: 3 ranks share each one by runs, so
    // 1.5 s in, every rank is inside an evaluation of a seed set's runs.
    let problem = repo("problems/ins_gnss.toml");
    for rank in [1, 2] {
        let dir = tempfile::tempdir().unwrap();
        let Some(out) = stop_rank(dir.path(), &["tune", &problem], libc::SIGTERM, rank) else {
            return;
        };
        stopped_by_sigterm(&out, rank);
        assert!(
            !dir.path().join("tuned").exists(),
            "nothing written by a job that failed"
        );
    }
}

#[test]
fn a_rank_killed_outright_ends_the_job_without_a_hang() {
    // SIGKILL leaves the rank no word: Open MPI ends the job, naming the rank, with the
    // signal's exit code 137 (128 + 9).
    let Some(out) = kill_rank(libc::SIGKILL, 2) else {
        return;
    };
    assert_eq!(out.code, Some(137), "{}", out.stderr);
    assert!(out.stderr.contains("rank 2"), "{}", out.stderr);
}

#[test]
fn each_ranks_workers_share_its_chunks() {
    let Some(bin) = mpi_bin() else { return };
    if !common_python() {
        return;
    }
    // 8 chunks on 2 ranks of 2 workers: each rank's chunks are every other one, and each
    // of its workers must get some (dealt by c mod 2, one worker of each rank would get
    // them all).
    let dir = tempfile::tempdir().unwrap();
    let p = walk(dir.path(), "good", 64 * 8);
    let text = std::fs::read_to_string(&p)
        .unwrap()
        .replace("workers = 1", "workers = 2");
    std::fs::write(&p, text).unwrap();
    let log = dir.path().join("requests.jsonl");
    let env = [("FAKE_WORKER_LOG", log.to_str().unwrap())];
    let out = output(&mut mpirun(
        &bin,
        2,
        dir.path(),
        &["check", p.to_str().unwrap()],
        &env,
    ));
    assert!(matches!(out.code, Some(0 | 1)), "{}", out.stderr);
    let mut requests = std::collections::BTreeMap::<u64, usize>::new();
    for line in std::fs::read_to_string(&log).unwrap().lines() {
        let v: serde_json::Value = serde_json::from_str(line).unwrap();
        *requests.entry(v["pid"].as_u64().unwrap()).or_default() += 1;
    }
    assert_eq!(requests.len(), 4, "four workers answered: {requests:?}");
    assert!(requests.values().all(|&n| n >= 2), "{requests:?}");
}

#[test]
fn a_build_without_the_mpi_feature_refuses_to_run_as_one_of_several_ranks() {
    // Each rank would run the whole check and print it.
    let dir = tempfile::tempdir().unwrap();
    let out = output(
        Command::cargo_bin("autotune")
            .unwrap()
            .args(["check", &repo("problems/cv1d.toml"), "--quiet"])
            .current_dir(dir.path())
            .env("OMPI_COMM_WORLD_SIZE", "3"),
    );
    assert_eq!(out.code, Some(2), "{}", out.stderr);
    assert_eq!(out.stderr.lines().count(), 1, "{}", out.stderr);
    assert!(
        out.stderr.contains("without the `mpi` feature"),
        "{}",
        out.stderr
    );
    // One rank (`srun` of a single task) is a plain run.
    let one_rank = output(
        Command::cargo_bin("autotune")
            .unwrap()
            .args(["check", &repo("problems/cv1d.toml"), "--quiet"])
            .current_dir(dir.path())
            .env("OMPI_COMM_WORLD_SIZE", "1"),
    );
    assert!(matches!(one_rank.code, Some(0 | 1)), "{}", one_rank.stderr);
}

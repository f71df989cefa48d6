//! A fuzzer for the shard format (`autotune merge`) and the C ABI of a worker that sums its
//! own records (`include/autotune.h`), issue 37: in the style of `tests/fuzz/inputs.rs`, on
//! stable Rust, inside the suite, from a fixed seed, every input run in a child process
//! under a memory limit.
//!
//! 1. Shard files. Three valid shards of a check of `problems/cv1d.toml` (150 runs, three
//!    chunks) are written once; first the hand-made hostile files of the issue (a count of
//!    10⁹ and of 2⁶², `n_x` = 2⁶³, NaN parameter bits, 10¹² runs, 10⁶ steps, a 300 MB
//!    `sums` field, a 600 MB file that stops being JSON after its head), then mutants: a
//!    node of the JSON replaced by a hostile value (huge, negative, fractional, NaN bits,
//!    wrong types, long strings), deleted or duplicated, a setting changed in every file
//!    alike (so that the merge gets past its comparison of the files), or bytes flipped,
//!    cut or inserted. Each is merged with the others in a random order.
//! 2. The C ABI. The test binary runs itself as a child (`c_abi_child`, ignored unless
//!    asked for), which makes random requests (valid, with fields made hostile, or with
//!    bytes mutated) and random sequences of calls on them: runs and steps inside and
//!    outside the request (0, T + 1, `SIZE_MAX`), NULL pointers, unknown or non-UTF-8
//!    sensor names, arrays of random shapes (their data always the size the shape says, as
//!    the header requires of a caller, or NULL), answers and frees at any point.
//!
//! Every run must exit 0, 1 or 2 (the child: 0), print no panic (a panic the C ABI catches
//! still prints), stay under 500 MB of resident memory and end within its bound; an exit-2
//! error must be one line naming a shard file or the problem. The budget is
//! `AUTOTUNE_FUZZ_SECONDS` (default 8 s), 60 / 40 % between the parts, and the seed
//! `AUTOTUNE_FUZZ_SEED` (default 1); the hand-made files come on top. Failing inputs are
//! saved under the cargo target's temporary directory (`fuzz-failures-cluster/`).

use std::ffi::{CStr, CString, OsString, c_char};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::fuzz_runner;
use crate::fuzzing;
use fuzz_runner::{Case, Tally, merge, run, run_program};
use fuzzing::{Rng, mutate_bytes, settings};
use serde_json::{Value, json};

/// How long a merge may take: the shards are kilobytes, the hand-made files are refused
/// while their head is read.
const MERGE_LIMIT: Duration = Duration::from_secs(30);

// ---------------------------------------------------------------------------------------
// 1. Shard files.

/// The three valid shards' JSON, written by `autotune check --shard i/3` in `dir`.
fn valid_shards(dir: &Path) -> Vec<Value> {
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("problems/cv1d.toml"),
        dir.join("cv1d.toml"),
    )
    .unwrap();
    (0..3)
        .map(|i| {
            let out = std::process::Command::new(env!("CARGO_BIN_EXE_autotune"))
                .current_dir(dir)
                .args(["check", "cv1d.toml", "--runs", "150", "--steps", "20"])
                .args([
                    "--shard",
                    &format!("{i}/3"),
                    "--sums-out",
                    &format!("s{i}.json"),
                ])
                .output()
                .unwrap();
            assert!(
                out.status.success(),
                "{}",
                String::from_utf8_lossy(&out.stderr)
            );
            let text = std::fs::read_to_string(dir.join(format!("s{i}.json"))).unwrap();
            serde_json::from_str(&text).unwrap()
        })
        .collect()
}

/// Values that have broken readers before.
fn hostile_value(rng: &mut Rng) -> Value {
    match rng.below(22) {
        0 => json!(0),
        1 => json!(-1),
        2 => json!(1),
        3 => json!(1_000_000_000u64),
        4 => json!(1u64 << 62),
        5 => json!(1u64 << 63),
        6 => json!(u64::MAX),
        7 => json!(1e308),
        8 => json!(2.5),
        9 => Value::Null,
        10 => json!(true),
        11 => json!(""),
        12 => json!("7ff8000000000000"),
        13 => json!("fff0000000000000"),
        14 => json!("not base64!"),
        15 => json!("QVRTVU1TMQA="),
        16 => json!([]),
        17 => json!({}),
        18 => json!("A".repeat(1 + rng.below(2_000_000))),
        19 => json!(-0.0),
        20 => json!(18446744073709551616.0),
        _ => json!([[1, 2], "x"]),
    }
}

/// Every node of `v`, as a path of object keys and array indices.
fn nodes(v: &Value, at: &mut Vec<Value>, out: &mut Vec<Vec<Value>>) {
    out.push(at.clone());
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                at.push(json!(k));
                nodes(x, at, out);
                at.pop();
            }
        }
        Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                at.push(json!(i));
                nodes(x, at, out);
                at.pop();
            }
        }
        _ => {}
    }
}

fn node_mut<'a>(v: &'a mut Value, path: &[Value]) -> &'a mut Value {
    path.iter().fold(v, |v, step| match step {
        Value::String(k) => &mut v[k.as_str()],
        Value::Number(i) => &mut v[i.as_u64().unwrap() as usize],
        _ => unreachable!(),
    })
}

/// A mutant of the three shards: JSON-level changes or bytes, as the texts to write.
fn mutant(shards: &[Value], rng: &mut Rng) -> Vec<Vec<u8>> {
    let mut files: Vec<Value> = shards.to_vec();
    let k = rng.below(3);
    match rng.below(6) {
        // A node replaced.
        0 | 1 => {
            let mut all = Vec::new();
            nodes(&files[k], &mut Vec::new(), &mut all);
            let path = rng.pick(&all[1..]).clone();
            *node_mut(&mut files[k], &path) = hostile_value(rng);
        }
        // A setting changed in every file alike.
        2 => {
            let keys: Vec<String> = files[0]["settings"]
                .as_object()
                .unwrap()
                .keys()
                .cloned()
                .collect();
            let key = rng.pick(&keys).clone();
            let value = hostile_value(rng);
            for f in &mut files {
                f["settings"][key.as_str()] = value.clone();
            }
        }
        // A key deleted, or a chunk duplicated or moved.
        3 => {
            let mut all = Vec::new();
            nodes(&files[k], &mut Vec::new(), &mut all);
            let path = rng.pick(&all[1..]).clone();
            let (last, parent) = path.split_last().unwrap();
            match (node_mut(&mut files[k], parent), last) {
                (Value::Object(m), Value::String(key)) => {
                    m.remove(key);
                }
                (Value::Array(a), Value::Number(i)) => {
                    let x = a[i.as_u64().unwrap() as usize].clone();
                    a.insert(rng.below(a.len() + 1), x);
                }
                _ => {}
            }
        }
        // The share or the count.
        4 => {
            let field = if rng.chance(0.5) { "index" } else { "count" };
            files[k]["shard"][field] = hostile_value(rng);
        }
        // Bytes.
        _ => {
            let mut texts: Vec<Vec<u8>> =
                files.iter().map(|f| f.to_string().into_bytes()).collect();
            for _ in 0..1 + rng.below(4) {
                mutate_bytes(&mut texts[k], rng);
            }
            return texts;
        }
    }
    files
        .iter()
        .map(|f| serde_json::to_vec_pretty(f).unwrap())
        .collect()
}

/// A `merge` of `texts` written as `a0.json` … in `dir` (in a random order, maybe with
/// --json).
fn merge_case(dir: &Path, kind: &str, texts: &[Vec<u8>], rng: &mut Rng) -> Case {
    let mut files: Vec<PathBuf> = Vec::new();
    for (i, t) in texts.iter().enumerate() {
        let p = dir.join(format!("a{i}.json"));
        std::fs::write(&p, t).unwrap();
        files.push(p);
    }
    let mut order: Vec<usize> = (0..files.len()).collect();
    for i in (1..order.len()).rev() {
        order.swap(i, rng.below(i + 1));
    }
    let json = rng.chance(0.3);
    let mut args: Vec<OsString> = vec!["merge".into()];
    args.extend(order.iter().map(|&i| files[i].clone().into_os_string()));
    if json {
        args.push("--json".into());
    }
    let mut names: Vec<String> = (0..texts.len()).map(|i| format!("a{i}.json")).collect();
    names.push("cv1d.toml".into());
    names.push("autotune merge".into());
    Case {
        kind: kind.into(),
        args,
        dir: dir.to_path_buf(),
        limit: MERGE_LIMIT,
        json,
        names,
        files,
    }
}

/// The shards with `change` made to every one (a setting), as texts.
fn alike(shards: &[Value], change: impl Fn(&mut Value)) -> Vec<Vec<u8>> {
    shards
        .iter()
        .map(|s| {
            let mut s = s.clone();
            change(&mut s);
            serde_json::to_vec_pretty(&s).unwrap()
        })
        .collect()
}

/// The hostile shard files the issue lists, each merged once.
fn hand_made(dir: &Path, shards: &[Value], failures_dir: &Path, tally: &mut Tally) {
    let mut rng = Rng(0xc105);
    let mut go = |kind: &str, texts: Vec<Vec<u8>>| {
        let case = merge_case(dir, &format!("hand-made/{kind}"), &texts, &mut rng);
        match run(&case, &[]) {
            Ok(o) if o.code == 2 => tally.ok(&case, &o),
            Ok(o) => tally.fail(
                &case,
                fuzz_runner::failed("a hostile shard merged", format!("exit {}", o.code)),
                failures_dir,
                "",
            ),
            Err(f) => tally.fail(&case, f, failures_dir, ""),
        }
    };
    go(
        "count 10^9",
        alike(shards, |s| s["shard"]["count"] = json!(1_000_000_000u64)),
    );
    go(
        "count 2^62",
        alike(shards, |s| s["shard"]["count"] = json!(1u64 << 62)),
    );
    go(
        "n_x 2^63",
        alike(shards, |s| s["settings"]["n_x"] = json!(1u64 << 63)),
    );
    go(
        "NaN parameter bits",
        alike(shards, |s| {
            s["settings"]["params"][0][1]["bits"] = json!("7ff8000000000000")
        }),
    );
    go(
        "10^12 runs",
        alike(shards, |s| {
            s["settings"]["runs"] = json!(1_000_000_000_000u64)
        }),
    );
    go(
        "10^6 steps",
        alike(shards, |s| s["settings"]["steps"] = json!(1_000_000)),
    );
    go(
        "lags near 10^6 steps",
        alike(shards, |s| {
            s["settings"]["steps"] = json!(1_000_000);
            s["settings"]["lags"] = json!(999_999);
        }),
    );
    let mut big = alike(shards, |_| {});
    let mut s1 = shards[1].clone();
    s1["chunks"][0]["sums"] = json!("");
    let text = serde_json::to_string_pretty(&s1).unwrap();
    let (head, tail) = text.split_at(text.find("\"sums\": \"\"").unwrap() + 9);
    let mut bytes = head.as_bytes().to_vec();
    bytes.resize(bytes.len() + 300_000_000, b'A');
    bytes.extend_from_slice(tail.as_bytes());
    big[1] = bytes;
    go("a 300 MB sums field", big);
    let mut junk = alike(shards, |_| {});
    let head = &junk[2][..junk[2].len() / 2].to_vec();
    let mut bytes = head.clone();
    bytes.resize(600_000_000, b'0');
    junk[2] = bytes;
    go("600 MB, not JSON after its head", junk);
    let _ = std::fs::remove_file(dir.join("a1.json"));
    let _ = std::fs::remove_file(dir.join("a2.json"));
}

// ---------------------------------------------------------------------------------------
// 2. The C ABI, in a child.

/// A request line and, when its layout is known (it parses, every dimension at most 3),
/// the state dimension and the sensors (name, m).
struct Request {
    line: Vec<u8>,
    layout: Option<(usize, Vec<(String, usize)>)>,
}

fn request(rng: &mut Rng) -> Request {
    let first = rng.below(200);
    let runs = [first, first + rng.below(70)];
    let steps = 1 + rng.below(40);
    let state = rng.below(4);
    let sensors: Vec<(String, usize)> = ["a", "b", "c"][..rng.below(4)]
        .iter()
        .map(|n| (n.to_string(), 1 + rng.below(3)))
        .collect();
    let mut v = json!({
        "id": rng.below(100),
        "runs": runs,
        "steps": steps,
        "theta": {"q": 1.0, "r": 2.0},
        "lags": rng.below(steps.min(6)),
        "layout": {
            "state": state,
            "sensors": sensors.iter().map(|(n, m)| json!({"name": n, "dim": m})).collect::<Vec<_>>(),
        },
    });
    match rng.below(4) {
        0 => {
            let key = *rng.pick(&["id", "runs", "steps", "theta", "lags", "layout"]);
            v[key] = hostile_value(rng);
        }
        1 => {
            let mut line = v.to_string().into_bytes();
            for _ in 0..1 + rng.below(3) {
                mutate_bytes(&mut line, rng);
            }
            let parsed: Option<Value> = serde_json::from_slice(&line).ok();
            let known = parsed.as_ref().and_then(layout_of);
            return Request {
                line,
                layout: known,
            };
        }
        _ => {}
    }
    let layout = layout_of(&v);
    Request {
        line: v.to_string().into_bytes(),
        layout,
    }
}

/// The layout a parsed request declares, if every dimension in it is small.
fn layout_of(v: &Value) -> Option<(usize, Vec<(String, usize)>)> {
    let small = |x: &Value| x.as_u64().filter(|&d| d <= 3).map(|d| d as usize);
    let state = match &v["layout"]["state"] {
        Value::Null => 0,
        x => small(x)?,
    };
    let sensors = v["layout"]["sensors"]
        .as_array()?
        .iter()
        .map(|s| Some((s["name"].as_str()?.to_string(), small(&s["dim"])?)))
        .collect::<Option<Vec<_>>>()?;
    Some((state, sensors))
}

/// One random call sequence on one request.
fn abi_session(rng: &mut Rng, stats: &mut [usize; 3]) {
    use autotune::internals::capi::*;
    let req = request(rng);
    let line = CString::new(req.line.iter().map(|&b| b.max(1)).collect::<Vec<u8>>()).unwrap();
    let text: *const c_char = if rng.chance(0.02) {
        std::ptr::null()
    } else {
        line.as_ptr()
    };
    // SAFETY: a NUL-terminated string or NULL.
    let c = unsafe { autotune_chunk_new(text) };
    let buf = vec![0.5f64; 64];
    let ptr = |rng: &mut Rng| {
        if rng.chance(0.05) {
            std::ptr::null()
        } else {
            buf.as_ptr()
        }
    };
    let (first, end, steps) = unsafe {
        (
            autotune_chunk_first_run(c),
            autotune_chunk_run_end(c),
            autotune_chunk_steps(c),
        )
    };
    let any = |rng: &mut Rng, lo: usize, hi: usize| match rng.below(8) {
        0 => usize::MAX,
        1 => 0,
        2 => hi + 1,
        3 => hi,
        _ => lo + rng.below(hi.saturating_sub(lo).max(1)),
    };
    let calls = if req.layout.is_some() || c.is_null() {
        rng.below(300)
    } else {
        0
    };
    let names: Vec<CString> = ["a", "b", "c", "zz", ""]
        .iter()
        .map(|n| CString::new(*n).unwrap())
        .collect();
    let bad_utf8 = CString::new(vec![0xffu8, 0xfe]).unwrap();
    for _ in 0..calls {
        let run = any(rng, first, end);
        let step = any(rng, 1, steps);
        let code = match rng.below(5) {
            // SAFETY: buffers of 64 doubles cover every dimension ≤ 3 (n², m² ≤ 9).
            0 => unsafe { autotune_chunk_state(c, run, step, ptr(rng), ptr(rng)) },
            1 => {
                let name = if rng.chance(0.05) {
                    bad_utf8.as_ptr()
                } else {
                    rng.pick(&names).as_ptr()
                };
                unsafe { autotune_chunk_sensor(c, run, step, name, ptr(rng), ptr(rng)) }
            }
            2 => {
                let why = rng.pick(&names).as_ptr();
                unsafe { autotune_chunk_diverged(c, run, step, why) }
            }
            _ => {
                let name =
                    CString::new(*rng.pick(&["e", "P", "nu_a", "S_a", "diverged", "x"])).unwrap();
                let ndim = rng.below(6);
                let mut shape: Vec<usize> = (0..ndim).map(|_| rng.below(8)).collect();
                if rng.chance(0.1) && ndim > 1 {
                    shape[0] = usize::MAX;
                    shape[1] = 3;
                }
                let len = shape.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
                // The data the shape says, as the header requires, or NULL.
                let data = vec![0.25f64; len.filter(|&n| n <= 1 << 16).unwrap_or(0)];
                let data_ptr = if len.is_some_and(|n| n <= 1 << 16) && rng.chance(0.95) {
                    data.as_ptr()
                } else {
                    std::ptr::null()
                };
                unsafe { autotune_chunk_array(c, name.as_ptr(), shape.as_ptr(), ndim, data_ptr) }
            }
        };
        stats[if code == 0 { 0 } else { 1 }] += 1;
        check_last_error();
    }
    if rng.chance(0.8) {
        // SAFETY: c from autotune_chunk_new (or NULL), not used again.
        let s = unsafe { autotune_chunk_answer(c) };
        if !s.is_null() {
            stats[2] += 1;
        }
        check_last_error();
        unsafe { autotune_string_free(s) };
    } else {
        unsafe { autotune_chunk_free(c) };
    }
}

/// A failure must never be the C ABI's caught panic.
fn check_last_error() {
    // SAFETY: a NUL-terminated string owned by this thread.
    let last = unsafe { CStr::from_ptr(autotune::internals::capi::autotune_last_error()) };
    let last = last.to_string_lossy();
    assert!(
        !last.contains("internal error"),
        "a panic inside the C ABI: {last}"
    );
}

/// The child: random sessions for the seconds and from the seed in
/// `AUTOTUNE_CAPI_FUZZ` (`SEED:SECONDS`). Ignored unless the parent test runs it.
#[test]
#[ignore = "run by fuzz_the_shard_format_and_the_c_abi in a child process"]
fn c_abi_child() {
    let Some(spec) = std::env::var("AUTOTUNE_CAPI_FUZZ").ok() else {
        return;
    };
    let (seed, seconds) = spec.split_once(':').unwrap();
    let mut rng = Rng(seed.parse().unwrap());
    let until = Instant::now() + Duration::from_secs_f64(seconds.parse().unwrap());
    let (mut sessions, mut stats) = (0, [0usize; 3]);
    while Instant::now() < until {
        abi_session(&mut rng, &mut stats);
        sessions += 1;
    }
    eprintln!(
        "c abi: {sessions} sessions, {} calls accepted, {} refused, {} answers",
        stats[0], stats[1], stats[2]
    );
}

// ---------------------------------------------------------------------------------------
// The test.

#[test]
fn fuzz_the_shard_format_and_the_c_abi() {
    let (seconds, seed, failures_dir) = settings("fuzz-failures-cluster");
    let dir = tempfile::tempdir().unwrap();
    let mut all = Tally::default();
    let start = Instant::now();
    let shard_dir = dir.path().join("shards");
    std::fs::create_dir_all(&shard_dir).unwrap();
    let shards = valid_shards(&shard_dir);

    // The valid shards merge: the plumbing works.
    let mut rng = Rng(seed);
    let texts = shards
        .iter()
        .map(|s| serde_json::to_vec_pretty(s).unwrap())
        .collect::<Vec<_>>();
    let case = merge_case(&shard_dir, "valid", &texts, &mut rng);
    let o = run(&case, &[]).unwrap_or_else(|f| panic!("{}", f.detail));
    assert!(o.code < 2, "valid shards: {}", o.error);

    let mut t = Tally::default();
    hand_made(&shard_dir, &shards, &failures_dir, &mut t);
    let elapsed = start.elapsed().as_secs_f64();
    t.summary("shards hand-made", seed, elapsed, elapsed, t.runs);
    merge(&mut all, t);

    let (mut t, t0, mut inputs) = (Tally::default(), Instant::now(), 0);
    let deadline = Instant::now() + Duration::from_secs_f64(seconds * 0.6);
    while Instant::now() < deadline {
        inputs += 1;
        let texts = mutant(&shards, &mut rng);
        let case = merge_case(&shard_dir, "shards/mutant", &texts, &mut rng);
        match run(&case, &[]) {
            Ok(o) => t.ok(&case, &o),
            Err(f) => t.fail(&case, f, &failures_dir, ""),
        }
    }
    t.summary(
        "shards",
        seed,
        seconds * 0.6,
        t0.elapsed().as_secs_f64(),
        inputs,
    );
    merge(&mut all, t);

    // The C ABI in a child: the test binary itself, running `c_abi_child`.
    let child_seconds = (seconds * 0.4).max(1.0);
    let spec = format!("{seed}:{child_seconds}");
    // The test's name in this binary: its module path without the crate's name.
    let child = module_path!()
        .split_once("::")
        .map_or("c_abi_child".to_string(), |(_, m)| {
            format!("{m}::c_abi_child")
        });
    let case = Case {
        kind: "c abi".into(),
        args: [
            child.as_str(),
            "--ignored",
            "--exact",
            "--nocapture",
            "--test-threads",
            "1",
        ]
        .iter()
        .map(|a| OsString::from(*a))
        .collect(),
        dir: dir.path().to_path_buf(),
        limit: Duration::from_secs_f64(child_seconds + 30.0),
        json: false,
        names: vec![],
        files: vec![],
    };
    let me = std::env::current_exe().unwrap();
    let mut t = Tally::default();
    match run_program(
        me.as_os_str(),
        &case,
        &[("AUTOTUNE_CAPI_FUZZ", spec.as_ref())],
    ) {
        Ok(o) if o.code == 0 => t.ok(&case, &o),
        Ok(o) => t.fail(
            &case,
            fuzz_runner::failed("the child failed", format!("exit {}: {}", o.code, o.error)),
            &failures_dir,
            "",
        ),
        Err(f) => t.fail(&case, f, &failures_dir, ""),
    }
    t.summary("c abi", seed, child_seconds, child_seconds, 1);
    merge(&mut all, t);

    assert!(
        all.failures == 0,
        "{} runs failed (inputs saved under {}):{}",
        all.failures,
        failures_dir.display(),
        all.report()
    );
}

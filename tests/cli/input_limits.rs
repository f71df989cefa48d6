//! Issue 21, items 5, 6, 7 and part of 16: every file a user names is read with bounded
//! memory and time. A FIFO or a device is refused instead of waited on or read for ever, a
//! line, a CSV header and a NumPy archive's expansion have documented caps, a CSV header is
//! parsed in time linear in its columns, huge numbers are shown in exponent form, and a
//! records file's fractional degrees of freedom are refused.
//!
//! Each run of the binary is watched: killed when its resident memory passes
//! [`RSS_LIMIT_KB`] or its time [`TIME_LIMIT`] (so a hang or a runaway reader fails the test
//! instead of blocking it or taking the machine's memory), and its peak resident memory is
//! taken from the kernel (`wait4`'s `ru_maxrss`).

#![cfg(unix)]

use std::io::Write;
use std::path::Path;
use std::time::{Duration, Instant};

use assert_cmd::cargo::CommandCargoExt;

/// Peak resident memory a hostile input may cost (the issue's bound), in KiB.
const RSS_LIMIT_KB: u64 = 500 * 1024;
/// Longest a refusal may take: each of these inputs is refused after a few reads.
const TIME_LIMIT: Duration = Duration::from_secs(20);

/// How a watched run of `autotune` ended.
#[derive(Debug)]
struct Outcome {
    /// Exit code (`None`: killed by a signal, the watchdog's too).
    code: Option<i32>,
    stderr: String,
    /// Peak resident memory, KiB.
    peak_kb: u64,
    /// Why the watchdog killed it, if it did.
    killed: Option<&'static str>,
}

fn rss_kb(pid: i32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Run `autotune args` in `dir`, watched.
fn run(dir: &Path, args: &[&str]) -> Outcome {
    let err_path = dir.join(format!("stderr-{}", std::process::id()));
    let err_file = std::fs::File::create(&err_path).unwrap();
    let child = std::process::Command::cargo_bin("autotune")
        .unwrap()
        .args(args)
        .current_dir(dir)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(err_file)
        .spawn()
        .unwrap();
    let pid = child.id() as i32;
    let start = Instant::now();
    let mut killed = None;
    let mut status = 0;
    // SAFETY: an all-zero rusage is a valid value; wait4 fills it.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        // SAFETY: `pid` is our own child, not yet reaped; the pointers are to live locals.
        let r = unsafe { libc::wait4(pid, &mut status, libc::WNOHANG, &mut usage) };
        if r == pid {
            break;
        }
        assert_eq!(r, 0, "wait4 failed");
        let over_memory = rss_kb(pid).is_some_and(|kb| kb > RSS_LIMIT_KB);
        if killed.is_none() && (over_memory || start.elapsed() > TIME_LIMIT) {
            killed = Some(if over_memory {
                "memory limit"
            } else {
                "time limit"
            });
            // SAFETY: signalling our own unreaped child.
            unsafe { libc::kill(pid, libc::SIGKILL) };
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    drop(child);
    let code = libc::WIFEXITED(status).then(|| libc::WEXITSTATUS(status));
    let stderr = std::fs::read_to_string(&err_path).unwrap_or_default();
    Outcome {
        code,
        stderr,
        peak_kb: usage.ru_maxrss as u64,
        killed,
    }
}

/// `autotune args` exits 2 within the limits with one line of stderr holding every `want`.
fn refused(dir: &Path, args: &[&str], want: &[&str]) -> Outcome {
    let o = run(dir, args);
    assert!(
        o.killed.is_none(),
        "{args:?}: killed at the {}: {o:?}",
        o.killed.unwrap()
    );
    assert_eq!(o.code, Some(2), "{args:?}: {o:?}");
    assert!(
        o.peak_kb < RSS_LIMIT_KB,
        "{args:?}: peak {} KiB: {o:?}",
        o.peak_kb
    );
    let lines: Vec<&str> = o.stderr.lines().collect();
    assert_eq!(lines.len(), 1, "{args:?}: not one line: {o:?}");
    for w in want {
        assert!(lines[0].contains(w), "{args:?}: no '{w}' in {}", lines[0]);
    }
    o
}

fn problem() -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("problems/cv1d.toml")
        .display()
        .to_string()
}

/// The four ways a records or measurement file is read from the command line.
fn readers(file: &str) -> Vec<Vec<String>> {
    let p = problem();
    let f = file.to_string();
    vec![
        vec!["check".into(), "--records".into(), f.clone()],
        vec![
            "check".into(),
            p.clone(),
            "--measurements".into(),
            f.clone(),
        ],
        vec!["estimate".into(), p, "--measurements".into(), f.clone()],
        vec!["nis".into(), f],
    ]
}

fn args(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

fn mkfifo(path: &Path) {
    let c = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
    // SAFETY: a valid NUL-terminated path.
    assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
}

#[test]
fn issue21_a_fifo_named_as_records_or_measurements_is_refused_not_waited_on() {
    let dir = tempfile::tempdir().unwrap();
    for name in ["r.csv", "r.jsonl", "r.npz", "r.npy", "r.toml"] {
        mkfifo(&dir.path().join(name));
    }
    let mut cases = readers("r.csv");
    cases.extend(readers("r.jsonl"));
    cases.push(vec!["check".into(), "--records".into(), "r.npz".into()]);
    cases.push(vec![
        "estimate".into(),
        problem(),
        "--measurements".into(),
        "r.npy".into(),
    ]);
    // A problem file, and a tuned config, are read through the same door.
    cases.push(vec!["check".into(), "r.toml".into()]);
    cases.push(vec![
        "check".into(),
        problem(),
        "--config".into(),
        "r.toml".into(),
    ]);
    for c in &cases {
        let file = c.iter().find(|a| a.starts_with("r.")).unwrap();
        refused(dir.path(), &args(c), &[file, "not a regular file"]);
    }
}

#[test]
fn issue21_dev_zero_behind_a_csv_name_is_refused_with_bounded_memory() {
    let dir = tempfile::tempdir().unwrap();
    std::os::unix::fs::symlink("/dev/zero", dir.path().join("x.csv")).unwrap();
    std::os::unix::fs::symlink("/dev/zero", dir.path().join("x.jsonl")).unwrap();
    let mut peak = 0;
    for file in ["x.csv", "x.jsonl"] {
        for c in readers(file) {
            let o = refused(dir.path(), &args(&c), &[file, "not a regular file"]);
            peak = peak.max(o.peak_kb);
        }
    }
    eprintln!("peak resident memory on /dev/zero: {peak} KiB");
}

/// A file of `len` bytes starting with `head`, the rest a hole (NUL bytes, no disk).
fn sparse(path: &Path, head: &[u8], len: u64) {
    let mut f = std::fs::File::create(path).unwrap();
    f.write_all(head).unwrap();
    f.set_len(len).unwrap();
}

#[test]
fn issue21_a_300_mb_line_is_refused_by_the_line_cap_quickly() {
    let dir = tempfile::tempdir().unwrap();
    let huge = 300_000_000;
    sparse(
        &dir.path().join("line.jsonl"),
        br#"{"run": 0, "step": 1, "nis": 1, "nis_dof": 1, "u": ["#,
        huge,
    );
    sparse(
        &dir.path().join("line.csv"),
        b"run,step,nis,nis_dof\n0,1,1,\"",
        huge,
    );
    sparse(&dir.path().join("zline.csv"), b"run,step,z_1\n0,1,\"", huge);
    sparse(
        &dir.path().join("zline.jsonl"),
        br#"{"run": 0, "step": 1, "z": ["#,
        huge,
    );
    let mut peak = 0;
    for (file, measurements) in [
        ("line.jsonl", false),
        ("line.csv", false),
        ("zline.csv", true),
        ("zline.jsonl", true),
    ] {
        // The records readers (check --records, nis) and the measurement readers (check and
        // estimate --measurements).
        let all = readers(file);
        let cases = if measurements {
            vec![all[1].clone(), all[2].clone()]
        } else {
            vec![all[0].clone(), all[3].clone()]
        };
        for c in cases {
            let start = Instant::now();
            let o = refused(
                dir.path(),
                &args(&c),
                &[file, "a line longer than the limit of 8 MiB"],
            );
            assert!(start.elapsed() < Duration::from_secs(10), "{c:?}: slow");
            peak = peak.max(o.peak_kb);
        }
    }
    eprintln!("peak resident memory on a 300 MB line: {peak} KiB");
}

#[test]
fn issue21_a_dense_json_line_just_over_the_cap_is_refused_before_parsing() {
    // One-digit numbers are what makes parsed JSON largest (a 30 MB line cost 620 MB).
    let dir = tempfile::tempdir().unwrap();
    let mut text = br#"{"run": 0, "step": 1, "nis": 1, "u": ["#.to_vec();
    while text.len() < (8 << 20) + 4096 {
        text.extend_from_slice(b"0,");
    }
    text.extend_from_slice(b"0]}\n");
    std::fs::write(dir.path().join("dense.jsonl"), text).unwrap();
    for c in [
        vec!["check", "--records", "dense.jsonl"],
        vec!["nis", "dense.jsonl"],
    ] {
        refused(dir.path(), &c, &["dense.jsonl:1", "longer than the limit"]);
    }
}

/// A zip archive (one deflated entry, `name`) holding `npy_header` and then `zeros` zero
/// bytes: what `np.savez_compressed` writes for an array of zeros.
fn npz_bomb(path: &Path, name: &str, npy_header: &[u8], zeros: u64) {
    use flate2::Compression;
    use flate2::write::DeflateEncoder;
    let mut crc = flate2::Crc::new();
    let mut enc = DeflateEncoder::new(Vec::new(), Compression::best());
    enc.write_all(npy_header).unwrap();
    crc.update(npy_header);
    let block = vec![0u8; 1 << 20];
    let mut left = zeros;
    while left > 0 {
        let n = left.min(block.len() as u64) as usize;
        enc.write_all(&block[..n]).unwrap();
        crc.update(&block[..n]);
        left -= n as u64;
    }
    let data = enc.finish().unwrap();
    let size = npy_header.len() as u32 + zeros as u32;
    let fname = name.as_bytes();
    let mut z = Vec::new();
    let u16le = |v: u16| v.to_le_bytes();
    let u32le = |v: u32| v.to_le_bytes();
    // Local file header.
    z.extend(u32le(0x0403_4b50));
    z.extend(u16le(20)); // version needed
    z.extend(u16le(0)); // flags
    z.extend(u16le(8)); // deflate
    z.extend(u16le(0)); // time
    z.extend(u16le(0x21)); // date
    z.extend(u32le(crc.sum()));
    z.extend(u32le(data.len() as u32));
    z.extend(u32le(size));
    z.extend(u16le(fname.len() as u16));
    z.extend(u16le(0));
    z.extend(fname);
    z.extend(&data);
    let central = z.len() as u32;
    z.extend(u32le(0x0201_4b50));
    z.extend(u16le(20)); // made by
    z.extend(u16le(20)); // needed
    z.extend(u16le(0));
    z.extend(u16le(8));
    z.extend(u16le(0));
    z.extend(u16le(0x21));
    z.extend(u32le(crc.sum()));
    z.extend(u32le(data.len() as u32));
    z.extend(u32le(size));
    z.extend(u16le(fname.len() as u16));
    z.extend(u16le(0)); // extra
    z.extend(u16le(0)); // comment
    z.extend(u16le(0)); // disk
    z.extend(u16le(0)); // internal attributes
    z.extend(u32le(0)); // external attributes
    z.extend(u32le(0)); // local header offset
    z.extend(fname);
    let central_len = z.len() as u32 - central;
    z.extend(u32le(0x0605_4b50));
    z.extend(u16le(0));
    z.extend(u16le(0));
    z.extend(u16le(1));
    z.extend(u16le(1));
    z.extend(u32le(central_len));
    z.extend(u32le(central));
    z.extend(u16le(0));
    std::fs::write(path, z).unwrap();
}

/// A version-1 `.npy` header for float64 data of `shape` (a Python tuple's text).
fn npy_header(shape: &str) -> Vec<u8> {
    let mut h = format!("{{'descr': '<f8', 'fortran_order': False, 'shape': {shape}, }}");
    while (10 + h.len() + 1) % 64 != 0 {
        h.push(' ');
    }
    h.push('\n');
    let mut bytes = b"\x93NUMPY\x01\x00".to_vec();
    bytes.extend((h.len() as u16).to_le_bytes());
    bytes.extend(h.as_bytes());
    bytes
}

#[test]
fn issue21_a_small_npz_that_expands_to_hundreds_of_megabytes_is_refused_before_allocating() {
    let dir = tempfile::tempdir().unwrap();
    // 50 million zeros: 400 MB of float64 in an archive of about 400 KB.
    let n: u64 = 50_000_000;
    npz_bomb(
        &dir.path().join("bomb.npz"),
        "e.npy",
        &npy_header(&format!("(1, {n}, 1)")),
        n * 8,
    );
    npz_bomb(
        &dir.path().join("z.npz"),
        "z.npy",
        &npy_header(&format!("({n}, 1)")),
        n * 8,
    );
    let len = std::fs::metadata(dir.path().join("bomb.npz"))
        .unwrap()
        .len();
    assert!(len < 2_000_000, "the archive is {len} bytes");
    let o1 = refused(
        dir.path(),
        &["check", "--records", "bomb.npz"],
        &["bomb.npz", "array e", "beyond the limit of 128 MiB"],
    );
    let o2 = refused(
        dir.path(),
        &["nis", "bomb.npz"],
        &["bomb.npz", "array e", "beyond the limit"],
    );
    let o3 = refused(
        dir.path(),
        &["estimate", &problem(), "--measurements", "z.npz"],
        &["z.npz", "array z", "beyond the limit"],
    );
    eprintln!(
        "peak resident memory on a {len}-byte npz of 400 MB: {} KiB",
        o1.peak_kb.max(o2.peak_kb).max(o3.peak_kb)
    );
}

#[test]
fn issue21_an_npy_header_longer_than_its_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    // Version 2: a 4-byte header length, here 4 GB, in a file of 12 bytes.
    let mut bytes = b"\x93NUMPY\x02\x00".to_vec();
    bytes.extend(u32::MAX.to_le_bytes());
    std::fs::write(dir.path().join("e.npy"), bytes).unwrap();
    refused(
        dir.path(),
        &["check", "--records", "e.npy"],
        &["e.npy", "a header of 4294967295 bytes"],
    );
}

/// A records CSV whose header has `run`, `step`, `e_1 … e_n` and the full `P_i_j` (n + n²
/// columns: a full covariance of 300 states is 90 000), and no rows.
fn wide_csv(dir: &Path, n: usize) -> std::path::PathBuf {
    let path = dir.join(format!("h{n}.csv"));
    let mut text = String::from("run,step");
    for i in 1..=n {
        text.push_str(&format!(",e_{i}"));
    }
    for i in 1..=n {
        for j in 1..=n {
            text.push_str(&format!(",P_{i}_{j}"));
        }
    }
    text.push('\n');
    std::fs::write(&path, text).unwrap();
    path
}

/// Seconds to scan `path`'s header, in this process.
fn header_seconds(path: &Path) -> f64 {
    let t = Instant::now();
    // A header without rows is refused once it is parsed: the parse is timed.
    let e = autotune::internals::records::scan_files(&[path.to_path_buf()]).unwrap_err();
    assert!(e.to_string().contains("no rows"), "{e}");
    t.elapsed().as_secs_f64()
}

#[test]
fn issue21_csv_header_parsing_is_linear_in_the_columns() {
    let dir = tempfile::tempdir().unwrap();
    // 10 100 and 100 172 columns.
    let small = wide_csv(dir.path(), 100);
    let large = wide_csv(dir.path(), 316);
    // Interleaved, the best of five each: other tests running alongside slow single runs.
    let (mut s, mut l) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..5 {
        s = s.min(header_seconds(&small));
        l = l.min(header_seconds(&large));
        if l > 60.0 * s.max(1e-3) && l > 2.0 {
            // Quadratic beyond doubt: the other rounds would take minutes.
            break;
        }
    }
    // Linear: ten times the columns, about ten times the time (here 12–36×, the larger
    // header's tables no longer fitting in cache); quadratic (main: 0.13 s and 26 s) is a
    // hundred times and more.
    assert!(
        l < 60.0 * s.max(1e-3),
        "10k columns {s:.4} s, 100k columns {l:.4} s"
    );
    eprintln!("10k columns {s:.4} s, 100k columns {l:.4} s");
}

#[test]
fn issue21_huge_numbers_of_seconds_are_shown_short() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("log.csv"), "time,sensor,nis,dof\n").unwrap();
    let o = refused(
        dir.path(),
        &["nis", "--follow", "log.csv", "--for", "1e300"],
        &["--for", "1e300"],
    );
    assert!(o.stderr.len() < 200, "{}", o.stderr);
    let toml = r#"name = "w"
state_names = ["x"]

[montecarlo]
runs = 10
steps = 5

[external]
command = ["./worker"]
sensors = { z = ["pos"] }
timeout = 1e300

[params.q]
value = 0.5
"#;
    std::fs::write(dir.path().join("w.toml"), toml).unwrap();
    let o = refused(
        dir.path(),
        &["check", "w.toml"],
        &["w.toml", "external.timeout", "1e300"],
    );
    assert!(o.stderr.len() < 200, "{}", o.stderr);
}

#[test]
fn issue21_records_refuse_a_fractional_dof() {
    let dir = tempfile::tempdir().unwrap();
    let files: [(&str, &str, &str); 3] = [
        (
            "nees.csv",
            "run,step,nees,nees_dof\n0,1,1,1.5\n0,2,1,1.5\n",
            "nees_dof is 1.5, not a whole number",
        ),
        (
            "nis.csv",
            "run,step,nis,nis_dof\n0,1,1,2.5\n0,2,1,2.5\n",
            "nis_dof is 2.5, not a whole number",
        ),
        (
            "nis.jsonl",
            "{\"run\": 0, \"step\": 1, \"nis\": 1, \"nis_dof\": 1.5}\n",
            "nis_dof is 1.5, not a whole number",
        ),
    ];
    for (name, text, want) in files {
        std::fs::write(dir.path().join(name), text).unwrap();
        refused(dir.path(), &["check", "--records", name], &[name, want]);
    }
    // The same file's whole degrees of freedom are read.
    std::fs::write(
        dir.path().join("whole.csv"),
        "run,step,nees,nees_dof\n0,1,1,2\n0,2,1,2\n",
    )
    .unwrap();
    let o = run(dir.path(), &["check", "--records", "whole.csv"]);
    assert!(matches!(o.code, Some(0) | Some(1)), "{o:?}");
}

/// Honest files are still read: the caps are far above them.
#[test]
fn issue21_ordinary_records_still_read() {
    let dir = tempfile::tempdir().unwrap();
    let mut text = String::from("run,step,nis,nis_dof\n");
    for r in 0..20 {
        for k in 1..=50 {
            text.push_str(&format!(
                "{r},{k},{},1\n",
                0.5 + ((r * 7 + k * 3) % 10) as f64 * 0.1
            ));
        }
    }
    std::fs::write(dir.path().join("ok.csv"), text).unwrap();
    let o = run(dir.path(), &["check", "--records", "ok.csv"]);
    assert!(matches!(o.code, Some(0) | Some(1)), "{o:?}");
}

#[test]
fn issue21_a_line_within_the_cap_cannot_declare_millions_of_components() {
    // Just under the line cap, four million one-digit components: the sums and the report
    // took 4.3 GB and 48 s before the components were capped.
    let dir = tempfile::tempdir().unwrap();
    let mut text = br#"{"run": 0, "step": 1, "nis": 1, "nis_dof": 1, "u": ["#.to_vec();
    while text.len() < (8 << 20) - 1024 {
        text.extend_from_slice(b"0,");
    }
    text.extend_from_slice(b"0]}\n");
    std::fs::write(dir.path().join("wide.jsonl"), text).unwrap();
    let o = refused(
        dir.path(),
        &["check", "--records", "wide.jsonl"],
        &[
            "wide.jsonl",
            "u has shape",
            "above the limit of 4096 components",
        ],
    );
    eprintln!(
        "peak resident memory on a line of 4 million components: {} KiB",
        o.peak_kb
    );
}

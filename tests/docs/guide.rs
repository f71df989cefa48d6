//! Issue 24: the user guide cannot go stale. Every command-and-output example in README.md
//! and in the guide (`docs/src/*.md`) is run here and its output compared with the page, so
//! a change to what autotune prints fails this test until the docs show the new output.
//!
//! An example is a ```` ```console ```` block: a line `$ COMMAND` (a trailing `# exit N`
//! comment states the exit code, 0 without one), then what it prints, stdout and then
//! stderr. Commands are `autotune …`, `cargo run --release -- …` (the same binary),
//! `cargo run --release --example NAME -- …` (the example's binary) and `cat FILE`.
//! Output lines that legitimately vary use snapbox's wildcards, as trycmd's pages do:
//! `[..]` inside a line, `...` as a line of its own for any lines.
//!
//! Each page runs in a scratch directory of its own, with copies of `problems/` and
//! `tuned/` and links to `tests/` and `examples/`, so commands read the shipped files by
//! their usual relative paths while everything they write (`tuned/cv2d.toml`, `out/…`,
//! `z.csv`) stays in the scratch directory; the commands of a page run in order there.
//!
//! `AUTOTUNE_BLESS=1 cargo test --release --test docs` writes the new output into the pages
//! (keeping the wildcards where they still match) instead of failing; read the diff before
//! committing it.
//!
//! Why a harness of our own around snapbox rather than trycmd on the pages: trycmd runs a
//! page's commands in the crate's root unless an `<page>.in/` directory beside every page
//! holds a copy of their input files, and in the root `autotune tune problems/cv2d.toml`
//! would overwrite the tracked `tuned/cv2d.toml`; here each page gets a scratch copy of the
//! inputs, exit codes read as shell comments (`# exit 1`), and the tests below can read the
//! same blocks (which of `check`'s lines the pages show).

use std::collections::{BTreeSet, HashSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use snapbox::IntoData;

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const BIN: &str = env!("CARGO_BIN_EXE_autotune");
/// Longest any one example may take. The whole test is meant to stay well under a minute
/// in release: an example that needs more belongs in a `sh` block without output.
const TIMEOUT: Duration = Duration::from_secs(60);

/// A fenced block of a page.
struct Fence {
    /// Its info string (`console`, `sh`, `toml`, …).
    info: String,
    /// 1-based line of the opening fence.
    line: usize,
    /// The lines between the fences, each with its byte offset in the page.
    body: Vec<(usize, String)>,
}

/// One `$ command` of a console block with the output the page shows.
struct Example {
    /// 1-based line of the `$`.
    line: usize,
    /// The command as written, without its `# …` comment.
    command: String,
    args: Vec<String>,
    exit: i32,
    expected: String,
    /// Byte range of the expected output in the page (for `AUTOTUNE_BLESS`).
    range: std::ops::Range<usize>,
}

/// README.md and every page of the guide, including those an `{{#include}}` pulls in.
fn pages() -> Vec<PathBuf> {
    let root = Path::new(ROOT);
    let mut pages = vec![root.join("README.md")];
    let mut dirs = vec![root.join("docs/src")];
    while let Some(dir) = dirs.pop() {
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                dirs.push(path);
            } else if path.extension().is_some_and(|e| e == "md") {
                pages.push(path);
            }
        }
    }
    pages.push(root.join("docs/ARCHITECTURE.md"));
    pages.sort();
    pages
}

fn rel(path: &Path) -> String {
    path.strip_prefix(ROOT)
        .unwrap_or(path)
        .display()
        .to_string()
}

/// The fenced blocks of a Markdown page (``` fences, as the pages use).
fn fences(text: &str) -> Vec<Fence> {
    let mut out = Vec::new();
    let mut open: Option<(usize, String, usize)> = None; // (line, info, fence width)
    let mut body = Vec::new();
    let mut offset = 0;
    for (i, line) in text.split_inclusive('\n').enumerate() {
        let trimmed = line.trim_end_matches('\n');
        let start = trimmed.trim_start();
        let ticks = start.chars().take_while(|&c| c == '`').count();
        match &open {
            None if ticks >= 3 => {
                open = Some((i + 1, start[ticks..].trim().to_string(), ticks));
                body.clear();
            }
            Some((_, _, width)) if ticks >= *width && start[ticks..].trim().is_empty() => {
                let (line, info, _) = open.take().unwrap();
                out.push(Fence {
                    info,
                    line,
                    body: std::mem::take(&mut body),
                });
            }
            Some(_) => body.push((offset, trimmed.to_string())),
            None => {}
        }
        offset += line.len();
    }
    assert!(open.is_none(), "an unclosed ``` fence");
    out
}

/// `line` split into words as a POSIX shell would, for the quoting the pages use ('…', "…",
/// backslashes); a word starting with `#` starts a comment, returned apart.
fn shell_words(line: &str) -> (Vec<String>, Option<String>) {
    let mut words = Vec::new();
    let mut word = String::new();
    let mut in_word = false;
    let mut chars = line.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '#' if !in_word => return (words, Some(chars.collect::<String>().trim().into())),
            ' ' | '\t' => {
                if in_word {
                    words.push(std::mem::take(&mut word));
                    in_word = false;
                }
            }
            '\'' => {
                in_word = true;
                for c in chars.by_ref() {
                    if c == '\'' {
                        break;
                    }
                    word.push(c);
                }
            }
            '"' => {
                in_word = true;
                while let Some(c) = chars.next() {
                    match c {
                        '"' => break,
                        '\\' => word.extend(chars.next()),
                        c => word.push(c),
                    }
                }
            }
            '\\' => {
                in_word = true;
                word.extend(chars.next());
            }
            c => {
                in_word = true;
                word.push(c);
            }
        }
    }
    if in_word {
        words.push(word);
    }
    (words, None)
}

/// The examples of every console block of `page`.
fn examples(page: &Path) -> Vec<Example> {
    let text = std::fs::read_to_string(page).unwrap();
    let mut out: Vec<Example> = Vec::new();
    for fence in fences(&text).into_iter().filter(|f| f.info == "console") {
        let first = fence.body.first().map(|(_, l)| l.as_str()).unwrap_or("");
        assert!(
            first.starts_with("$ "),
            "{}:{}: a console block starts with `$ command`",
            rel(page),
            fence.line
        );
        for (n, (offset, line)) in fence.body.iter().enumerate() {
            let end = offset + line.len() + 1;
            if let Some(command) = line.strip_prefix("$ ") {
                let (args, comment) = shell_words(command);
                let exit = match comment.as_deref().and_then(|c| c.strip_prefix("exit ")) {
                    Some(code) => code
                        .split_whitespace()
                        .next()
                        .and_then(|c| c.parse().ok())
                        .unwrap_or_else(|| {
                            panic!(
                                "{}:{}: `# exit N` wants a number",
                                rel(page),
                                fence.line + n + 1
                            )
                        }),
                    None => 0,
                };
                let command = match command.find(" #") {
                    Some(i) if comment.is_some() => command[..i].trim_end(),
                    _ => command,
                };
                out.push(Example {
                    line: fence.line + n + 1,
                    command: command.to_string(),
                    args,
                    exit,
                    expected: String::new(),
                    range: end..end,
                });
            } else {
                let ex = out.last_mut().unwrap();
                ex.expected.push_str(line);
                ex.expected.push('\n');
                ex.range.end = end;
            }
        }
    }
    out
}

/// The program an example runs and its arguments, or why it cannot run.
enum Program {
    Bin(PathBuf, Vec<String>),
    Cat(String),
}

fn program(ex: &Example) -> Result<Program, String> {
    let a: Vec<&str> = ex.args.iter().map(String::as_str).collect();
    let rest = |n: usize| a[n..].iter().map(|s| s.to_string()).collect();
    match a.as_slice() {
        ["autotune", ..] => Ok(Program::Bin(BIN.into(), rest(1))),
        ["cargo", "run", "--release", "--", ..] => Ok(Program::Bin(BIN.into(), rest(4))),
        ["cargo", "run", "--release", "--example", name, "--", ..] => {
            Ok(Program::Bin(example_binary(name)?, rest(6)))
        }
        ["cat", file] => Ok(Program::Cat(file.to_string())),
        _ => Err(format!(
            "unsupported command `{}`: a console block runs autotune, `cargo run --release [--example NAME] --` or `cat`",
            ex.command
        )),
    }
}

/// The binary of example `name`, built once by cargo (a no-op after `cargo test`, which
/// builds the examples; `cargo test --test docs` alone does not).
fn example_binary(name: &str) -> Result<PathBuf, String> {
    static BUILT: Mutex<Option<HashSet<String>>> = Mutex::new(None);
    let bin_dir = Path::new(BIN).parent().unwrap();
    let path = bin_dir.join("examples").join(name);
    let mut built = BUILT.lock().unwrap();
    let built = built.get_or_insert_with(HashSet::new);
    if built.insert(name.to_string()) {
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        cmd.current_dir(ROOT)
            .args(["build", "--quiet", "--example", name]);
        if bin_dir.ends_with("release") {
            cmd.arg("--release");
        }
        let out = cmd.output().map_err(|e| format!("cargo build: {e}"))?;
        if !out.status.success() {
            return Err(format!(
                "cargo build --example {name}: {}",
                String::from_utf8_lossy(&out.stderr)
            ));
        }
    }
    Ok(path)
}

/// A scratch directory laid out like the repository for a page's commands: copies of the
/// files commands may write over, links to the ones they only read.
fn sandbox() -> tempfile::TempDir {
    let dir = tempfile::Builder::new()
        .prefix("autotune-docs-")
        .tempdir()
        .unwrap();
    for sub in ["problems", "tuned"] {
        std::fs::create_dir(dir.path().join(sub)).unwrap();
        for entry in std::fs::read_dir(Path::new(ROOT).join(sub)).unwrap() {
            let path = entry.unwrap().path();
            std::fs::copy(&path, dir.path().join(sub).join(path.file_name().unwrap())).unwrap();
        }
    }
    for sub in ["tests", "examples", "docs"] {
        std::os::unix::fs::symlink(Path::new(ROOT).join(sub), dir.path().join(sub)).unwrap();
    }
    dir
}

/// Runs `ex` in `dir`: its exit code and what it printed (stdout, then stderr).
fn run(ex: &Example, dir: &Path) -> Result<(i32, String), String> {
    let (bin, args) = match program(ex)? {
        Program::Cat(file) => {
            let text =
                std::fs::read_to_string(dir.join(&file)).map_err(|e| format!("cat {file}: {e}"))?;
            return Ok((0, text));
        }
        Program::Bin(bin, args) => (bin, args),
    };
    let out_dir = tempfile::tempdir().unwrap();
    let stdout = out_dir.path().join("stdout");
    let stderr = out_dir.path().join("stderr");
    let mut cmd = Command::new(&bin);
    cmd.args(&args)
        .current_dir(dir)
        .stdin(Stdio::null())
        .stdout(std::fs::File::create(&stdout).unwrap())
        .stderr(std::fs::File::create(&stderr).unwrap())
        .env_remove("NO_COLOR");
    for (key, _) in std::env::vars() {
        if key.starts_with("AUTOTUNE_") || key.starts_with("RAYON_") {
            cmd.env_remove(key);
        }
    }
    let mut child = cmd.spawn().map_err(|e| format!("{}: {e}", bin.display()))?;
    let start = Instant::now();
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if start.elapsed() > TIMEOUT {
            let _ = child.kill();
            let _ = child.wait();
            return Err(format!(
                "took longer than {} s: too slow for a doc example",
                TIMEOUT.as_secs()
            ));
        }
        std::thread::sleep(Duration::from_millis(5));
    };
    let mut text = std::fs::read_to_string(&stdout).unwrap();
    text.push_str(&std::fs::read_to_string(&stderr).unwrap());
    Ok((status.code().unwrap_or(-1), text))
}

/// Whether `actual` matches the page's `expected` (snapbox's wildcards, the scratch
/// directory shown as `[CWD]`), and the actual output with the page's wildcards kept where
/// they still match, for `AUTOTUNE_BLESS`.
fn compare(expected: &str, actual: &str, dir: &Path) -> (Result<(), String>, String) {
    let mut redactions = snapbox::Redactions::new();
    redactions
        .insert("[CWD]", dir.canonicalize().unwrap())
        .unwrap();
    let assert = snapbox::Assert::new()
        .redact_with(redactions)
        .normalize_paths(false);
    let (actual, expected) = assert.normalize(actual.into_data(), expected.into_data());
    let blessed = actual.render().unwrap_or_default();
    let result = assert
        .try_eq(Some(&"autotune"), actual, expected)
        .map_err(|e| e.to_string());
    (result, blessed)
}

#[test]
fn every_example_in_the_readme_and_the_guide_prints_what_the_page_shows() {
    let bless = std::env::var_os("AUTOTUNE_BLESS").is_some_and(|v| v == "1");
    let mut failures = Vec::new();
    let mut count = 0;
    let total = Instant::now();
    for page in pages() {
        let examples = examples(&page);
        if examples.is_empty() {
            continue;
        }
        let dir = sandbox();
        let started = Instant::now();
        let mut text = std::fs::read_to_string(&page).unwrap();
        let mut edits = Vec::new();
        for ex in &examples {
            count += 1;
            let at = format!("{}:{}: `{}`", rel(&page), ex.line, ex.command);
            let (code, actual) = match run(ex, dir.path()) {
                Ok(r) => r,
                Err(e) => {
                    failures.push(format!("{at}: {e}"));
                    continue;
                }
            };
            let (result, blessed) = compare(&ex.expected, &actual, dir.path());
            if code != ex.exit {
                failures.push(format!(
                    "{at}: exit {code}, the page says {} (a `# exit N` comment on the command line; none means 0); it printed:\n{actual}",
                    ex.exit
                ));
            }
            if let Err(diff) = result {
                if bless {
                    edits.push((ex.range.clone(), blessed));
                } else {
                    failures.push(format!("{at}: the output differs from the page\n{diff}"));
                }
            }
        }
        for (range, new) in edits.into_iter().rev() {
            text.replace_range(range, &new);
        }
        if bless {
            std::fs::write(&page, text).unwrap();
        }
        eprintln!(
            "{}: {} examples in {:.1} s",
            rel(&page),
            examples.len(),
            started.elapsed().as_secs_f64()
        );
    }
    eprintln!("{count} examples in {:.1} s", total.elapsed().as_secs_f64());
    assert!(count > 0, "no console examples found");
    assert!(
        failures.is_empty(),
        "{} of {count} doc examples failed (AUTOTUNE_BLESS=1 writes the new output into the pages):\n\n{}",
        failures.len(),
        failures.join("\n\n")
    );
}

/// A block that shows a `$ command` is an example and must be a console block, which the
/// test above runs; commands shown without output (installation, pip) go in `sh` blocks
/// without a prompt.
#[test]
fn every_block_with_a_prompt_is_an_executed_example() {
    let mut bad = Vec::new();
    for page in pages() {
        let text = std::fs::read_to_string(&page).unwrap();
        for fence in fences(&text) {
            if fence.info != "console" && fence.body.iter().any(|(_, l)| l.starts_with("$ ")) {
                bad.push(format!("{}:{} ```{}", rel(&page), fence.line, fence.info));
            }
        }
        for ex in examples(&page) {
            if let Err(e) = program(&ex) {
                bad.push(format!("{}:{}: {e}", rel(&page), ex.line));
            }
        }
    }
    assert!(
        bad.is_empty(),
        "blocks with `$ ` prompts that the doc test would not run:\n{}",
        bad.join("\n")
    );
}

/// The `check` summaries the pages show: the expected output of every `check` example
/// that prints one (not `--json`, `--quiet`).
fn shown_check_lines() -> Vec<String> {
    let mut lines = Vec::new();
    for page in pages() {
        for ex in examples(&page) {
            let Ok(Program::Bin(_, args)) = program(&ex) else {
                continue;
            };
            if args.first().is_some_and(|a| a == "check")
                && !args
                    .iter()
                    .any(|a| a == "--json" || a == "--quiet" || a == "-q")
            {
                lines.extend(ex.expected.lines().map(String::from));
            }
        }
    }
    lines
}

/// The string literals of `writeln!(out, "…")` and `format!("…")` calls in `text`.
fn format_literals(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for opener in ["writeln!(", "format!("] {
        let mut rest = text;
        while let Some(i) = rest.find(opener) {
            rest = &rest[i + opener.len()..];
            let call = rest.trim_start();
            let call = call
                .strip_prefix("out,")
                .or_else(|| call.strip_prefix("stdout,"))
                .unwrap_or(call)
                .trim_start();
            let Some(body) = call.strip_prefix('"') else {
                continue;
            };
            let mut lit = String::new();
            let mut chars = body.chars();
            while let Some(c) = chars.next() {
                match c {
                    '"' => break,
                    '\\' => match chars.next() {
                        Some('n') => lit.push('\n'),
                        Some(c) => lit.push(c),
                        None => {}
                    },
                    c => lit.push(c),
                }
            }
            out.push(lit);
        }
    }
    out
}

/// A format string as a pattern: its literal text, `{…}` standing for anything.
fn matches_template(template: &str, line: &str) -> bool {
    let mut parts = Vec::new();
    let mut lit = String::new();
    let mut chars = template.chars().peekable();
    while let Some(c) = chars.next() {
        match c {
            '{' if chars.peek() == Some(&'{') => {
                chars.next();
                lit.push('{');
            }
            '}' if chars.peek() == Some(&'}') => {
                chars.next();
                lit.push('}');
            }
            '{' => {
                for c in chars.by_ref() {
                    if c == '}' {
                        break;
                    }
                }
                parts.push(std::mem::take(&mut lit));
            }
            c => lit.push(c),
        }
    }
    parts.push(lit);
    // Anchored at both ends, each literal part in order.
    let (first, rest) = parts.split_first().unwrap();
    let Some(mut tail) = line.strip_prefix(first.as_str()) else {
        return false;
    };
    for (i, part) in rest.iter().enumerate() {
        if i + 1 == rest.len() {
            return tail.ends_with(part.as_str());
        }
        match tail.find(part.as_str()) {
            Some(at) => tail = &tail[at + part.len()..],
            None => return false,
        }
    }
    true
}

/// The body of `fn name` in `source` (up to the next line that is a lone `}`).
fn function_body<'a>(source: &'a str, name: &str) -> &'a str {
    let start = source.find(&format!("fn {name}(")).unwrap_or_else(|| {
        panic!("fn {name} not found: update CHECK_LINES in tests/docs/guide.rs")
    });
    let end = source[start..].find("\n}\n").unwrap() + start;
    &source[start..end]
}

/// Where `check` prints its summary: the file and the functions whose formatted lines
/// (and line fragments) make it up. If the code moves, move these names with it.
const CHECK_LINES: &[(&str, &[&str])] = &[
    (
        "src/report/check/summary.rs",
        &[
            "check_summary",
            "summary_text",
            "stat_row",
            "component_lines",
            "mean_lines",
            "whiteness_line",
            "power_notes",
            "gate_text",
        ],
    ),
    (
        "src/report/consistency/cells.rs",
        &["no_data_reason", "run_spread_note"],
    ),
];

/// Fragments of `check`'s lines that no example in the pages shows, and why. Every other
/// line and fragment the summary can print appears in a `check` example of the README or
/// the guide, so a change to any of them fails the doc-example test.
const NOT_SHOWN: &[(&str, &str)] = &[(
    "the A{} test has no data: no step of the {} runs × {} steps had {}",
    "needs a problem whose sensors never report in a whole run; the other no-data line (every run stopped) is shown",
)];

/// Changing any printed line of `check` must fail a doc-example test: every line (and
/// every variant of a line's fixed text) that `check`'s summary is built from appears in
/// some `check` example the pages show, and is therefore compared byte for byte.
#[test]
fn every_kind_of_line_check_prints_is_shown_in_the_docs() {
    let shown = shown_check_lines();
    let mut missing = Vec::new();
    let mut templates = BTreeSet::new();
    for (file, functions) in CHECK_LINES {
        let source = std::fs::read_to_string(Path::new(ROOT).join(file)).unwrap();
        for f in *functions {
            for lit in format_literals(function_body(&source, f)) {
                // Only templates of whole lines or of the text after a line's label;
                // error messages and numbers are not summary lines.
                if lit.trim().is_empty() || lit.starts_with('{') && lit.len() < 6 {
                    continue;
                }
                templates.insert(lit);
            }
        }
    }
    assert!(
        templates.len() > 15,
        "found only {} templates",
        templates.len()
    );
    for t in &templates {
        if NOT_SHOWN.iter().any(|(n, _)| n == t) {
            continue;
        }
        let t_line = t.trim_end_matches('\n');
        let whole = shown.iter().any(|l| matches_template(t_line, l));
        // A fragment (the gate's text after "  gate: ", a note after "  note: ") appears
        // inside a line.
        let fragment = shown.iter().any(|l| {
            (0..l.len())
                .filter(|&i| l.is_char_boundary(i))
                .any(|i| matches_template(t_line, &l[i..]))
        });
        if !whole && !fragment {
            missing.push(t.clone());
        }
    }
    // Every verdict `check` can reach, in the words of its last line.
    use autotune::internals::stats::Verdict;
    let verdicts = [
        Verdict::Consistent,
        Verdict::Overconfident,
        Verdict::Underconfident,
        Verdict::Mixed,
        Verdict::NotWhite,
        Verdict::Biased,
        Verdict::Inconclusive,
        Verdict::Diverged,
        Verdict::IllConditioned,
        Verdict::TruthOverflow,
    ];
    // A new verdict fails to compile here until it is listed above.
    let _exhaustive = |v: Verdict| match v {
        Verdict::Consistent
        | Verdict::Overconfident
        | Verdict::Underconfident
        | Verdict::Mixed
        | Verdict::NotWhite
        | Verdict::Biased
        | Verdict::Inconclusive
        | Verdict::Diverged
        | Verdict::IllConditioned
        | Verdict::TruthOverflow => (),
    };
    for v in verdicts {
        let line = format!("verdict: {}", v.describe());
        if !shown.contains(&line) && !VERDICTS_NOT_SHOWN.contains(&v.label()) {
            missing.push(line);
        }
    }
    assert!(
        missing.is_empty(),
        "lines of `check` no example in the README or the guide shows (add one, or list it in NOT_SHOWN with the reason):\n{}",
        missing.join("\n")
    );
}

/// Verdicts `check` can print that no example shows, by label: "diverged" and "truth
/// overflow" need a filter or a truth that breaks down, and "not white" time averages inside
/// their intervals with correlated innovations, which no shipped problem has at a cheap
/// setting (tests/gate/gate.rs, tests/cli/hardening.rs and tests/cli/bad_input.rs test them).
const VERDICTS_NOT_SHOWN: &[&str] = &["diverged", "truth overflow", "not white"];

#[test]
fn the_template_matcher_reads_format_strings() {
    assert!(matches_template("  gate: {}", "  gate: full (…)"));
    assert!(matches_template("  A{:<5} {:>10}", "  ANEES     5.4316"));
    assert!(!matches_template("  params: {}", "  stat    time-avg"));
    assert!(matches_template(
        "{} in {} of {} runs{first}",
        "filter diverged in 3 of 200 runs"
    ));
    assert_eq!(
        format_literals("writeln!(\n out,\n \"  a {x} \\\"b\\\"\"\n);"),
        vec!["  a {x} \"b\"".to_string()]
    );
}

/// mdBook's anchor for a heading: lower case, letters, digits, `_` and `-` kept, spaces
/// as `-`, the rest dropped.
fn anchor(heading: &str) -> String {
    heading
        .trim()
        .chars()
        .filter_map(|c| {
            if c.is_alphanumeric() || c == '_' || c == '-' {
                Some(c.to_lowercase().next().unwrap())
            } else if c.is_whitespace() {
                Some('-')
            } else {
                None
            }
        })
        .collect()
}

fn anchors(page: &Path) -> HashSet<String> {
    let text = std::fs::read_to_string(page).unwrap();
    let mut in_fence = false;
    let mut out = HashSet::new();
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            in_fence = !in_fence;
        } else if !in_fence && line.starts_with('#') {
            out.insert(anchor(line.trim_start_matches('#')));
        }
    }
    out
}

/// Every relative link of the README and the guide leads to a file that exists, and to a
/// heading of it where it names one; the README links into the guide, not to moved pages.
#[test]
fn links_between_the_pages_resolve() {
    let mut bad = Vec::new();
    for page in pages() {
        let text = std::fs::read_to_string(&page).unwrap();
        let mut in_fence = false;
        for (n, line) in text.lines().enumerate() {
            if line.trim_start().starts_with("```") {
                in_fence = !in_fence;
                continue;
            }
            if in_fence {
                continue;
            }
            let mut rest = line;
            while let Some(i) = rest.find("](") {
                rest = &rest[i + 2..];
                let Some(end) = rest.find(')') else { break };
                let target = &rest[..end];
                rest = &rest[end..];
                if target.contains("://") || target.starts_with("mailto:") {
                    continue;
                }
                let (file, frag) = match target.split_once('#') {
                    Some((f, a)) => (f, Some(a)),
                    None => (target, None),
                };
                let path = if file.is_empty() {
                    page.clone()
                } else {
                    page.parent().unwrap().join(file)
                };
                let at = format!("{}:{}: {target}", rel(&page), n + 1);
                if !path.exists() {
                    bad.push(format!("{at}: no such file"));
                } else if frag.is_some_and(|frag| {
                    path.extension().is_some_and(|e| e == "md") && !anchors(&path).contains(frag)
                }) {
                    bad.push(format!("{at}: no such heading"));
                }
            }
        }
    }
    assert!(bad.is_empty(), "broken links:\n{}", bad.join("\n"));
}

/// Every page in docs/src is a chapter of the book (SUMMARY.md lists it), so none is left
/// out of `mdbook build` and its examples are seen by a reader.
#[test]
fn every_page_of_the_guide_is_in_its_summary() {
    let src = Path::new(ROOT).join("docs/src");
    let summary = std::fs::read_to_string(src.join("SUMMARY.md")).unwrap();
    let missing: Vec<String> = pages()
        .into_iter()
        .filter(|p| p.starts_with(&src) && !p.ends_with("SUMMARY.md"))
        .map(|p| p.strip_prefix(&src).unwrap().display().to_string())
        .filter(|p| !summary.contains(&format!("]({p})")))
        .collect();
    assert!(
        missing.is_empty(),
        "pages not in docs/src/SUMMARY.md: {missing:?}"
    );
}

//! Issue 40: files a reader can hold. No source file of src/ is over 500 lines before its
//! unit-test module (`#[cfg(test)]`); the files that are themselves test modules (a
//! `tests.rs` or a file under a `tests/` folder, declared under `#[cfg(test)]`) are tests.

use std::path::Path;

use super::architecture::rust_files;

/// The most lines a source file may have before its test module.
const MAX_LINES: usize = 500;

/// Lines of `text` before its first `#[cfg(test)]` line.
fn code_lines(text: &str) -> usize {
    text.lines()
        .take_while(|l| !l.starts_with("#[cfg(test)]"))
        .count()
}

/// Whether `file` is a test module itself: `tests.rs`, or under a `tests/` folder.
fn is_test_module(src: &Path, file: &Path) -> bool {
    let rel = file.strip_prefix(src).unwrap();
    rel.file_name().is_some_and(|n| n == "tests.rs")
        || rel.components().any(|c| c.as_os_str() == "tests")
}

#[test]
fn no_source_file_is_over_500_lines_before_its_tests() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut long: Vec<String> = files
        .iter()
        .filter(|f| !is_test_module(&src, f))
        .filter_map(|f| {
            let n = code_lines(&std::fs::read_to_string(f).unwrap());
            (n > MAX_LINES)
                .then(|| format!("{} ({n} lines)", f.strip_prefix(&src).unwrap().display()))
        })
        .collect();
    long.sort();
    assert!(
        long.is_empty(),
        "over {MAX_LINES} lines before their tests: {long:?}"
    );
    assert!(
        files.len() > 100,
        "src/ was not found: {} files",
        files.len()
    );
}

#[test]
fn the_count_stops_at_the_test_module_and_skips_test_files() {
    assert_eq!(code_lines("a\nb\n#[cfg(test)]\nmod tests {\n}\n"), 2);
    assert_eq!(code_lines("a\n    #[cfg(test)]\nb\n"), 3);
    let src = Path::new("/s");
    assert!(is_test_module(src, Path::new("/s/explain/tests.rs")));
    assert!(is_test_module(src, Path::new("/s/tune/tests/mock.rs")));
    assert!(!is_test_module(src, Path::new("/s/tune/tuner.rs")));
}

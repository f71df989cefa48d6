//! Issue 24: man pages generated from the clap definitions (clap_mangen), committed under
//! docs/man/ so that a packager or a user can install them, and compared here with what the
//! code renders, so that they cannot go stale: a changed flag or help text fails this test
//! until `AUTOTUNE_BLESS=1 cargo test --release --test man` writes the new pages.

use std::collections::BTreeMap;
use std::path::Path;

use clap::CommandFactory;

/// The pages the code renders: `autotune.1` and one per subcommand (`autotune-check.1`, …).
fn rendered() -> BTreeMap<String, String> {
    let dir = tempfile::tempdir().unwrap();
    clap_mangen::generate_to(autotune::app::Cli::command(), dir.path()).unwrap();
    read_pages(dir.path())
}

fn read_pages(dir: &Path) -> BTreeMap<String, String> {
    let mut pages = BTreeMap::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "1") {
            let name = path.file_name().unwrap().to_string_lossy().into_owned();
            pages.insert(name, std::fs::read_to_string(&path).unwrap());
        }
    }
    pages
}

#[test]
fn the_committed_man_pages_are_what_the_command_line_renders() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs/man");
    let want = rendered();
    assert!(want.contains_key("autotune.1") && want.contains_key("autotune-check.1"));
    if std::env::var_os("AUTOTUNE_BLESS").is_some_and(|v| v == "1") {
        std::fs::create_dir_all(&dir).unwrap();
        for (name, _) in read_pages(&dir) {
            if !want.contains_key(&name) {
                std::fs::remove_file(dir.join(name)).unwrap();
            }
        }
        for (name, text) in &want {
            std::fs::write(dir.join(name), text).unwrap();
        }
        return;
    }
    let have = read_pages(&dir);
    let names = |m: &BTreeMap<String, String>| m.keys().cloned().collect::<Vec<_>>();
    assert_eq!(
        names(&have),
        names(&want),
        "docs/man/ has other pages than the command line renders (AUTOTUNE_BLESS=1 rewrites them)"
    );
    let stale: Vec<&String> = want
        .iter()
        .filter(|(name, text)| have[*name] != **text)
        .map(|(name, _)| name)
        .collect();
    assert!(
        stale.is_empty(),
        "docs/man/ pages differ from what the command line renders: {stale:?}; \
         `AUTOTUNE_BLESS=1 cargo test --release --test man` rewrites them"
    );
}

/// The pages say what a reader of `man autotune-check` needs: the flags and their help.
#[test]
fn the_check_page_documents_its_flags() {
    let pages = rendered();
    let check = &pages["autotune-check.1"];
    for flag in [
        "\\-\\-config",
        "\\-\\-junit",
        "\\-\\-nis\\-only",
        "\\-\\-records",
    ] {
        assert!(check.contains(flag), "autotune-check.1 lacks {flag}");
    }
    assert!(pages["autotune.1"].contains("autotune\\-check(1)"));
}

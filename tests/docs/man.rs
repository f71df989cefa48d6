//! Issue 24: man pages generated from the clap definitions (clap_mangen), committed under
//! docs/man/ so that a packager or a user can install them, and compared here with what the
//! code renders, so that they cannot go stale: a changed flag or help text fails this test
//! until `AUTOTUNE_BLESS=1 cargo test --release --test docs -- man::` writes the new pages.

use std::collections::BTreeMap;
use std::path::Path;

use clap::CommandFactory;

/// The pages the code renders: `autotune.1` and one per subcommand (`autotune-check.1`, …),
/// each SYNOPSIS with the value every option takes (clap_mangen lists `[--runs]` alone).
fn rendered() -> BTreeMap<String, String> {
    let dir = tempfile::tempdir().unwrap();
    let cli = autotune::app::Cli::command();
    clap_mangen::generate_to(cli.clone(), dir.path()).unwrap();
    let mut pages = read_pages(dir.path());
    for sub in cli.get_subcommands() {
        if let Some(page) = pages.get_mut(&format!("autotune-{}.1", sub.get_name())) {
            *page = with_values(page, sub);
        }
    }
    pages
}

/// `page` with each option of its SYNOPSIS followed by its value, as its OPTIONS section
/// shows it: `[\fB\-\-runs\fR \fI<RUNS>\fR]`, `[\fB\-\-set\fR \fI<NAME=VALUE>\fR...]`.
fn with_values(page: &str, cmd: &clap::Command) -> String {
    let mut lines: Vec<String> = page.lines().map(str::to_string).collect();
    let Some(at) = lines.iter().position(|l| l == ".SH SYNOPSIS") else {
        return page.to_string();
    };
    let mut synopsis = lines[at + 1].clone();
    for arg in cmd.get_arguments() {
        let (Some(long), true) = (arg.get_long(), arg.get_action().takes_values()) else {
            continue;
        };
        let flag = format!("\\fB\\-\\-{}\\fR", long.replace('-', "\\-"));
        let value = arg
            .get_value_names()
            .and_then(|v| v.first())
            .map(|v| v.to_string())
            .unwrap_or_else(|| arg.get_id().as_str().to_uppercase());
        let many = arg.get_num_args().is_some_and(|n| n.max_values() > 1);
        let dots = if many { "..." } else { "" };
        let with = format!("{flag} \\fI<{value}>\\fR{dots}");
        synopsis = synopsis.replace(&format!("{flag}]"), &format!("{with}]"));
    }
    lines[at + 1] = synopsis;
    let mut out = lines.join("\n");
    out.push('\n');
    out
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
         `AUTOTUNE_BLESS=1 cargo test --release --test docs -- man::` rewrites them"
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
    // The SYNOPSIS names each option's value (issue 37, item 13).
    let synopsis = check
        .lines()
        .skip_while(|l| *l != ".SH SYNOPSIS")
        .nth(1)
        .unwrap();
    for shown in [
        "[\\fB\\-\\-records\\fR \\fI<FILE>\\fR...]",
        "[\\fB\\-\\-runs\\fR \\fI<RUNS>\\fR]",
        "[\\fB\\-\\-set\\fR \\fI<NAME=VALUE>\\fR]",
        "[\\fB\\-\\-junit\\fR \\fI<FILE>\\fR]",
        "[\\fB\\-\\-json\\fR]",
    ] {
        assert!(synopsis.contains(shown), "{shown} not in {synopsis}");
    }
}

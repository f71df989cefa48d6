//! What the command line prints on stdout and stderr: the summaries, coloured on a terminal
//! that wants colour; a closed pipe quietly; an error as one line, and the exit codes.

use std::process::ExitCode;

use super::error::AppError;
use crate::report::paint_verdicts;

/// 0 for a pass, 1 for a verdict that fails.
pub(super) fn exit_code(pass: bool) -> ExitCode {
    if pass {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(1)
    }
}

/// `text` on `out`, its verdict lines coloured when stdout is a terminal that wants colour.
pub(super) fn write_painted(
    out: &mut dyn std::io::Write,
    text: &str,
    pass: bool,
) -> std::io::Result<()> {
    if colour_enabled() {
        out.write_all(paint_verdicts(text, pass).as_bytes())
    } else {
        out.write_all(text.as_bytes())
    }
}

/// Print on stdout with `f`. A closed pipe (`autotune check … | head`) ends the printing
/// without an error, so the command still exits with its verdict's code; any other failure
/// of stdout is an error.
pub(super) fn print_stdout(
    f: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<(), AppError> {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    match f(&mut stdout).and_then(|()| stdout.flush()) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(()),
        r => Ok(r?),
    }
}

/// Print an error as `error: …` on stderr and map it to exit code 2. A closed stdout pipe
/// is not an error here: `check` and `tune` print through [`print_stdout`] and keep their
/// verdict's code, and what else prints (help, `init`, `completions`) has done its work.
pub(super) fn finish(result: Result<ExitCode, AppError>) -> ExitCode {
    match result {
        Ok(code) => code,
        Err(AppError::Io(e)) if e.kind() == std::io::ErrorKind::BrokenPipe => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

/// Whether to colour stdout: only on a terminal, and never when `NO_COLOR` is set to
/// anything non-empty (<https://no-color.org>).
pub(super) fn colour_enabled() -> bool {
    use std::io::IsTerminal;
    std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty()) && std::io::stdout().is_terminal()
}

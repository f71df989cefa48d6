//! `init`: write a commented starter problem file.
//!
//! Each starter (`templates/<model>.toml`) is a complete problem file whose comments explain
//! every section and field. Its filter parameters EQUAL the truth's noise, so `autotune check`
//! passes on it unchanged with the Monte Carlo seed it ships with (the integration tests in
//! `tests/cli/init.rs` run that check for every model); the comments tell the user to replace
//! the values with their own guesses, which `autotune tune` then corrects.

use std::path::PathBuf;

use clap::ValueEnum;

use super::{CommandError, OneOf};
use crate::output::write_file;
use crate::report::init::init_text;

/// The starter models: `--model`, its help, its errors and the completions all list these.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Model {
    /// 1-D nearly constant velocity, position measured (parameters q_accel, r_pos)
    Cv1d,
    /// 2-D nearly constant velocity, per-axis noise, position measured (q_accel_x/y, r_pos_x/y)
    Cv2d,
    /// DC motor in continuous time, encoder angle measured (q_torque, q_voltage, r_angle)
    Dcmotor,
}

/// What every template writes where the problem name goes.
const NAME_PLACEHOLDER: &str = "{{name}}";

/// The `[external]` starter: a worker's problem file (no truth of its own to check).
const EXTERNAL_TEMPLATE: &str = include_str!("templates/external.toml");

impl Model {
    /// The template, with [`NAME_PLACEHOLDER`] for the name.
    fn template(self) -> &'static str {
        match self {
            Model::Cv1d => include_str!("templates/cv1d.toml"),
            Model::Cv2d => include_str!("templates/cv2d.toml"),
            Model::Dcmotor => include_str!("templates/dcmotor.toml"),
        }
    }

    /// The starter problem file for problem `name` (already validated by [`parse_name`]).
    fn starter(self, name: &str) -> String {
        self.template().replace(NAME_PLACEHOLDER, name)
    }
}

/// The options of `init`.
#[derive(Debug, Clone, clap::Args)]
pub struct InitOptions {
    /// Problem name (letters, digits, '_' and '-'): written as `name = "NAME"`, and the
    /// default file is NAME.toml.
    #[arg(value_parser = parse_name)]
    pub name: String,
    /// Which system the starter models.
    #[arg(long, default_value = "cv2d", value_parser = OneOf::<Model>::new())]
    pub model: Model,
    /// Write a starter for a filter in another program, run as a worker (external,
    /// docs/src/workers.md), instead of a built-in model.
    #[arg(long, conflicts_with = "model")]
    pub external: bool,
    /// File to write (default: NAME.toml in the current directory).
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Overwrite the file if it exists.
    #[arg(long)]
    pub force: bool,
}

/// Why a problem name is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    /// No characters.
    #[error("the name is empty: use letters, digits, '_' and '-'")]
    Empty,
    /// A character other than ASCII letters, digits, `_` and `-`.
    #[error("{0:?} is not allowed: use letters, digits, '_' and '-' only")]
    Character(char),
}

/// A problem name: non-empty, ASCII letters, digits, `_` and `-` only (it becomes a file
/// name and a TOML string).
fn parse_name(name: &str) -> Result<String, NameError> {
    if name.is_empty() {
        return Err(NameError::Empty);
    }
    if let Some(c) = name
        .chars()
        .find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '-'))
    {
        return Err(NameError::Character(c));
    }
    Ok(name.to_string())
}

/// Run `init`: write the starter problem file (never over an existing file unless
/// `force`); returns what it printed.
pub fn init(a: &InitOptions) -> Result<String, CommandError> {
    let path = a
        .out
        .clone()
        .unwrap_or_else(|| PathBuf::from(format!("{}.toml", a.name)));
    // symlink_metadata: a dangling symlink or any other entry counts as existing.
    if !a.force && std::fs::symlink_metadata(&path).is_ok() {
        return Err(CommandError::Exists {
            path: path.display().to_string(),
        });
    }
    if a.external {
        let text = EXTERNAL_TEMPLATE.replace(NAME_PLACEHOLDER, &a.name);
        write_file(&path, text.as_bytes(), a.force).map_err(|e| e.of_flag("--out"))?;
        return Ok(init_text(&path, None));
    }
    write_file(&path, a.model.starter(&a.name).as_bytes(), a.force)
        .map_err(|e| e.of_flag("--out"))?;
    let model = a
        .model
        .to_possible_value()
        .map(|v| v.get_name().to_string());
    Ok(init_text(&path, Some(model.as_deref().unwrap_or_default())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::problem::Problem;
    use clap::builder::TypedValueParser;
    use std::ffi::OsStr;
    use std::path::Path;

    #[test]
    fn names() {
        for ok in ["cv2d", "my-filter_2", "A", "_"] {
            assert_eq!(parse_name(ok).as_deref(), Ok(ok));
        }
        for bad in ["", "a b", "a/b", "a.toml", "x\"y", "ä", "a\nb"] {
            assert!(parse_name(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn every_template_is_a_valid_problem_with_its_name() {
        for &m in Model::value_variants() {
            let t = m.template();
            assert!(
                t.contains(&format!("name = \"{NAME_PLACEHOLDER}\"")),
                "{m:?}"
            );
            let text = m.starter("some-name_1");
            assert!(!text.contains("{{"), "{m:?}: placeholder left");
            let p = Problem::from_toml(&text, Path::new("starter.toml"))
                .unwrap_or_else(|e| panic!("{m:?}: {e}"));
            assert_eq!(p.name(), "some-name_1");
        }
        let text = EXTERNAL_TEMPLATE.replace(NAME_PLACEHOLDER, "ext");
        let p = Problem::from_toml(&text, Path::new("starter.toml")).expect("external starter");
        assert_eq!(p.name(), "ext");
    }

    #[test]
    fn unknown_value_error_lists_the_known_ones_on_its_first_line() {
        use clap::Parser;
        for (args, known) in [
            (
                &["autotune", "init", "x", "--model", "cv3d"][..],
                "(known: cv1d, cv2d, dcmotor)",
            ),
            (
                &["autotune", "completions", "tcsh"][..],
                "(known: bash, elvish, fish, powershell, zsh)",
            ),
        ] {
            let err = crate::app::Cli::try_parse_from(args).unwrap_err();
            let text = err.render().to_string();
            let first = text.lines().next().unwrap();
            assert!(
                first.contains(&format!("'{}'", args[args.len() - 1])),
                "{first}"
            );
            assert!(first.contains(known), "{first}");
        }
        let cmd = clap::Command::new("t");
        let ok = OneOf::<Model>::new().parse_ref(&cmd, None, OsStr::new("dcmotor"));
        assert_eq!(ok.unwrap(), Model::Dcmotor);
    }
}

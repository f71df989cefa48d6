//! How numbers are printed in every report: four significant digits (`fmt_g`), fixed
//! decimals that turn scientific when huge (`fmt_fixed`), signed means (`fmt_signed`), and
//! long plain numbers inside finished text made compact (`compact_numbers`).

/// `text` with its `verdict:` lines in bold green (`pass`) or bold red (ANSI colours, for a
/// terminal that shows them).
pub fn paint_verdicts(text: &str, pass: bool) -> String {
    let code = if pass { "1;32" } else { "1;31" };
    let mut out = String::with_capacity(text.len() + 16);
    for line in text.split_inclusive('\n') {
        let (body, end) = match line.strip_suffix('\n') {
            Some(b) => (b, "\n"),
            None => (line, ""),
        };
        if body.starts_with("verdict:") {
            out.push_str(&format!("\x1b[{code}m{body}\x1b[0m{end}"));
        } else {
            out.push_str(line);
        }
    }
    out
}

/// A number with four significant digits, in scientific notation when it is very small or
/// very large.
pub fn fmt_g(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{v:.3e}")
    } else {
        let digits = if a == 0.0 {
            0
        } else {
            (3 - a.log10().floor() as i32).max(0) as usize
        };
        format!("{v:.digits$}")
    }
}

/// Longest plain decimal number [`compact_numbers`] leaves as it is.
const LONGEST_PLAIN_NUMBER: usize = 20;

/// `text` with every plain decimal number longer than 20 characters rewritten as
/// [`fmt_fixed`] writes it (scientific notation, four significant digits), for text that
/// was built elsewhere with fixed decimals (the diagnosis's evidence): there a value of
/// 10¹⁰⁰ is a hundred digits.
pub(crate) fn compact_numbers(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while let Some(start) = rest.find(|c: char| c.is_ascii_digit()) {
        out.push_str(&rest[..start]);
        let tail = &rest[start..];
        let len = tail
            .find(|c: char| !(c.is_ascii_digit() || c == '.'))
            .unwrap_or(tail.len());
        let token = &tail[..len];
        match token.parse::<f64>() {
            Ok(v) if len > LONGEST_PLAIN_NUMBER => out.push_str(&fmt_fixed(v, 3)),
            _ => out.push_str(token),
        }
        rest = &tail[len..];
    }
    out.push_str(rest);
    out
}

/// Magnitude from which [`fmt_fixed`] switches to scientific notation.
const FIXED_LIMIT: f64 = 1e6;

/// A signed number with `decimals` decimals ("+0.02"), in scientific notation from the same
/// size as [`fmt_fixed`]; a value that rounds to zero shows as "+0.00", never "-0.00".
pub fn fmt_signed(v: f64, decimals: usize) -> String {
    if v.abs() >= FIXED_LIMIT && v.is_finite() {
        format!("{v:+.3e}")
    } else if v.abs() < 0.5 * 10f64.powi(-(decimals as i32)) {
        format!("{:+.decimals$}", 0.0)
    } else {
        format!("{v:+.decimals$}")
    }
}

/// A number with `decimals` decimals, as `{:.decimals$}` prints it, but in scientific
/// notation with four significant digits from a magnitude of 10⁶ on, so that a number such
/// as the ANEES of an overflowing filter prints as `1.234e127` rather than as 128 digits.
pub fn fmt_fixed(v: f64, decimals: usize) -> String {
    if v.abs() >= FIXED_LIMIT && v.is_finite() {
        format!("{v:.3e}")
    } else {
        format!("{v:.decimals$}")
    }
}

/// One end as text: the value, or `≤ v` / `≥ v` where the trace stopped at its limit.
fn end_text(e: &crate::estimate::RangeEnd, lower: bool) -> String {
    match (e.reached, lower) {
        (true, true) if e.value == 0.0 => "0".to_string(),
        (true, _) => fmt_g(e.value),
        (false, true) => format!("≤ {}", fmt_g(e.value)),
        (false, false) => format!("≥ {}", fmt_g(e.value)),
    }
}

/// A range as `lo … hi`, or `missing` in its place.
pub fn range_text(r: Option<&crate::estimate::Range>, missing: &str) -> String {
    r.map_or_else(
        || missing.to_string(),
        |r| {
            format!(
                "{} … {}",
                end_text(&r.lower, true),
                end_text(&r.upper, false)
            )
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_numbers_print_in_scientific_notation_and_ordinary_ones_as_before() {
        assert_eq!(fmt_fixed(3.98765432, 4), "3.9877");
        assert_eq!(fmt_fixed(-12.5, 2), "-12.50");
        assert_eq!(fmt_fixed(999_999.0, 4), "999999.0000");
        assert_eq!(fmt_fixed(1.5e127, 4), "1.500e127");
        assert_eq!(fmt_fixed(-2e6, 4), "-2.000e6");
        assert_eq!(fmt_fixed(f64::NAN, 4), "NaN");
        assert_eq!(fmt_fixed(f64::INFINITY, 4), "inf");
        assert_eq!(fmt_g(1e308), "1.000e308");
        assert_eq!(fmt_g(0.5), "0.5000");
        assert!(fmt_fixed(f64::MAX, 4).len() < 12);
        let long = format!("ν²/S = {:.3}, ρ₁ = +0.916", 1e100);
        assert_eq!(compact_numbers(&long), "ν²/S = 1.000e100, ρ₁ = +0.916");
        assert_eq!(
            compact_numbers("e²/P = 2.500 at 1e5"),
            "e²/P = 2.500 at 1e5"
        );
    }
}

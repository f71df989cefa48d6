//! The names of recorded quantities (`e`, `P`, `nu_radar`, `nis_dof_radar`, …) and of the
//! CSV columns that flatten them (`P_1_2`, `nu_radar_1`).

/// The name of the experiment recorded in `files`, for reports and output paths: the
/// first file's stem, or, when that stem names a quantity (the per-quantity arrays
/// `e.npy`, `P.npy`, … of one experiment), the name of the directory holding the files
/// (`records` if it has none). Every character but an ASCII letter, digit or `-` becomes
/// `_`.
pub fn experiment_name(files: &[std::path::PathBuf]) -> String {
    let stem = |p: &std::path::Path| p.file_stem().and_then(|s| s.to_str()).map(str::to_owned);
    let name = files.first().and_then(|first| match stem(first) {
        Some(s) if Quantity::parse(&s).is_none() => Some(s),
        _ => {
            let dir = match first.parent() {
                Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
                _ => std::path::PathBuf::from("."),
            };
            let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
            dir.file_name().and_then(|s| s.to_str()).map(str::to_owned)
        }
    });
    match name {
        Some(n) if !n.is_empty() => n
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .collect(),
        _ => "records".to_string(),
    }
}

/// A recorded quantity, with its sensor where it has one (empty: the unnamed sensor).
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub enum Quantity {
    /// Run index.
    Run,
    /// Step (1-based).
    Step,
    /// Estimation error, n.
    E,
    /// Truth state, n.
    X,
    /// Estimate, n.
    Xhat,
    /// Covariance, n × n.
    P,
    /// Precomputed NEES.
    Nees,
    /// Its degrees of freedom.
    NeesDof,
    /// `e_j²/P_jj`, n.
    E2p,
    /// Innovation of a sensor, m.
    Nu(String),
    /// Its covariance, m × m.
    S(String),
    /// Precomputed NIS of a sensor.
    Nis(String),
    /// Its degrees of freedom.
    NisDof(String),
    /// `ν_j/√S_jj`, m.
    U(String),
    /// The run's filter broke down at this step.
    Diverged,
}

impl Quantity {
    /// Parse a quantity's name (`nu_radar`, `P`, `nis_dof`).
    pub fn parse(name: &str) -> Option<Quantity> {
        let sensor = |rest: &str| -> Option<String> {
            if rest.is_empty() {
                return Some(String::new());
            }
            let s = rest.strip_prefix('_')?;
            valid_sensor(s).then(|| s.to_string())
        };
        Some(match name {
            "run" => Quantity::Run,
            "step" => Quantity::Step,
            "e" => Quantity::E,
            "x" => Quantity::X,
            "xhat" => Quantity::Xhat,
            "P" => Quantity::P,
            "nees" => Quantity::Nees,
            "nees_dof" => Quantity::NeesDof,
            "e2p" => Quantity::E2p,
            "diverged" => Quantity::Diverged,
            _ => {
                if let Some(rest) = name.strip_prefix("nis_dof") {
                    Quantity::NisDof(sensor(rest)?)
                } else if let Some(rest) = name.strip_prefix("nis") {
                    Quantity::Nis(sensor(rest)?)
                } else if let Some(rest) = name.strip_prefix("nu") {
                    Quantity::Nu(sensor(rest)?)
                } else if let Some(rest) = name.strip_prefix('S') {
                    Quantity::S(sensor(rest)?)
                } else if let Some(rest) = name.strip_prefix('u') {
                    Quantity::U(sensor(rest)?)
                } else {
                    return None;
                }
            }
        })
    }

    /// The number of indices beyond (run, step): 0 for a scalar, 1 for a vector, 2 for a
    /// matrix.
    pub fn rank(&self) -> usize {
        match self {
            Quantity::E | Quantity::X | Quantity::Xhat | Quantity::E2p => 1,
            Quantity::Nu(_) | Quantity::U(_) => 1,
            Quantity::P | Quantity::S(_) => 2,
            _ => 0,
        }
    }

    /// The quantity's name: the NumPy array's and the JSON key, and the CSV columns' prefix
    /// (`P`, `nu_radar`).
    pub fn name(&self) -> String {
        let (base, s) = match self {
            Quantity::Run => ("run", ""),
            Quantity::Step => ("step", ""),
            Quantity::E => ("e", ""),
            Quantity::X => ("x", ""),
            Quantity::Xhat => ("xhat", ""),
            Quantity::P => ("P", ""),
            Quantity::Nees => ("nees", ""),
            Quantity::NeesDof => ("nees_dof", ""),
            Quantity::E2p => ("e2p", ""),
            Quantity::Diverged => ("diverged", ""),
            Quantity::Nu(s) => ("nu", s.as_str()),
            Quantity::S(s) => ("S", s.as_str()),
            Quantity::Nis(s) => ("nis", s.as_str()),
            Quantity::NisDof(s) => ("nis_dof", s.as_str()),
            Quantity::U(s) => ("u", s.as_str()),
        };
        if s.is_empty() {
            base.to_string()
        } else {
            format!("{base}_{s}")
        }
    }

    /// The sensor the quantity belongs to, if any.
    pub fn sensor(&self) -> Option<&str> {
        match self {
            Quantity::Nu(s) | Quantity::S(s) | Quantity::Nis(s) | Quantity::NisDof(s) => Some(s),
            Quantity::U(s) => Some(s),
            _ => None,
        }
    }
}

/// Whether `s` is a sensor name: a letter, then letters, digits and `_`, and not `dof`.
pub fn valid_sensor(s: &str) -> bool {
    let mut chars = s.chars();
    chars.next().is_some_and(|c| c.is_ascii_alphabetic())
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && s != "dof"
        && !s.starts_with("dof_")
}

/// Parse a CSV column name: the quantity and its 1-based indices turned 0-based
/// (`P_1_2` → (P, [0, 1]), `nu_radar_2` → (nu_radar, [1])). A sensor name ending in `_<digits>`
/// is read as the longest name whose index count matches the quantity.
pub fn parse_column(name: &str) -> Option<(Quantity, Vec<usize>)> {
    let parts: Vec<&str> = name.split('_').collect();
    for k in (0..=2usize).rev() {
        if k >= parts.len() {
            continue;
        }
        let (base, idx) = parts.split_at(parts.len() - k);
        let Some(idx) = idx
            .iter()
            .map(|p| {
                p.parse::<usize>()
                    .ok()
                    .filter(|&i| i >= 1 && !p.starts_with('0'))
            })
            .collect::<Option<Vec<usize>>>()
        else {
            continue;
        };
        if let Some(q) = Quantity::parse(&base.join("_"))
            && q.rank() == k
        {
            return Some((q, idx.into_iter().map(|i| i - 1).collect()));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_with_and_without_a_sensor() {
        assert_eq!(
            Quantity::parse("nu_radar"),
            Some(Quantity::Nu("radar".into()))
        );
        assert_eq!(Quantity::parse("nu"), Some(Quantity::Nu(String::new())));
        assert_eq!(
            Quantity::parse("nis_dof_gps_2"),
            Some(Quantity::NisDof("gps_2".into()))
        );
        assert_eq!(
            Quantity::parse("nis_dof"),
            Some(Quantity::NisDof(String::new()))
        );
        assert_eq!(
            Quantity::parse("nis_gps"),
            Some(Quantity::Nis("gps".into()))
        );
        assert_eq!(Quantity::parse("S_1radar"), None);
        assert_eq!(Quantity::parse("nusance"), None);
        assert_eq!(Quantity::parse("Q"), None);
    }

    #[test]
    fn columns_parse_their_indices() {
        assert_eq!(parse_column("P_1_2"), Some((Quantity::P, vec![0, 1])));
        assert_eq!(parse_column("e_4"), Some((Quantity::E, vec![3])));
        assert_eq!(
            parse_column("nu_radar_2"),
            Some((Quantity::Nu("radar".into()), vec![1]))
        );
        assert_eq!(
            parse_column("S_gs1_2_1"),
            Some((Quantity::S("gs1".into()), vec![1, 0]))
        );
        assert_eq!(
            parse_column("nis_gps_2"),
            Some((Quantity::Nis("gps_2".into()), vec![]))
        );
        assert_eq!(
            parse_column("nu_gps_2_1"),
            Some((Quantity::Nu("gps_2".into()), vec![0]))
        );
        assert_eq!(parse_column("nees"), Some((Quantity::Nees, vec![])));
        assert_eq!(parse_column("e_0"), None);
        assert_eq!(parse_column("e"), None);
        assert_eq!(parse_column("P_1"), None);
    }
}

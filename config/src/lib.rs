//! Loading RON configuration files with errors a person can act on: every error names the file,
//! the line and column, and the field, whether the file does not parse or a value is out of range.
//!
//! Parsing (serde + ron) gives positions for syntax and type errors; semantic checks done after
//! parsing go through one [`Checker`] (finite, positive, counts, [`Bound`]s with their reasons),
//! which finds the field's position again with [`locate`].

mod check;
mod kind;

use std::path::Path;

use serde::de::DeserializeOwned;

pub use check::{At, Bound, Checker, Limit};
pub use kind::{
    expect_kind, find_kind, load_file_kind, parse_kind, peek_kind, with_kind, FileKind, KindEntry,
};

/// An error in a configuration file.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}", self.render())]
pub struct ConfigError {
    /// File path, or a name such as "configs/rig-spidar-h.ron (built in)".
    pub origin: String,
    pub line: usize,
    pub column: usize,
    /// Dotted path of the offending field, e.g. `hands[1].strings[2].anchor_m`.
    pub field: String,
    /// What is wrong and what to do about it.
    pub message: String,
}

impl ConfigError {
    fn render(&self) -> String {
        if self.line == 0 {
            format!("{}: {}", self.origin, self.message)
        } else {
            format!("{}:{}:{}: {}: {}", self.origin, self.line, self.column, self.field, self.message)
        }
    }
}

/// Largest configuration file read (4 MiB): the biggest real one (a keyframe set) is a few
/// hundred KiB, and a path such as `/dev/zero` or a log file given by mistake must not be read
/// until memory runs out.
pub const MAX_FILE_BYTES: u64 = 4 << 20;

/// Reads and parses a RON file; I/O errors are reported with the path.
pub fn load_file<T: DeserializeOwned>(path: &Path) -> Result<(T, String), ConfigError> {
    let text = read_capped(path, MAX_FILE_BYTES)?;
    let value = parse(&text, &path.display().to_string())?;
    Ok((value, text))
}

/// Reads a text file of at most `cap` bytes (reading stops one byte past the cap, so a device
/// or a pipe that never ends is refused too).
pub fn read_capped(path: &Path, cap: u64) -> Result<String, ConfigError> {
    use std::io::Read;
    let err = |message: String| ConfigError {
        origin: path.display().to_string(),
        line: 0,
        column: 0,
        field: "(file)".into(),
        message,
    };
    let file = std::fs::File::open(path).map_err(|e| err(format!("cannot read the file: {e}")))?;
    let mut bytes = Vec::new();
    file.take(cap + 1).read_to_end(&mut bytes).map_err(|e| err(format!("cannot read the file: {e}")))?;
    if bytes.len() as u64 > cap {
        return Err(err(format!("larger than {} MiB: not a configuration file (check the path)", cap >> 20)));
    }
    String::from_utf8(bytes).map_err(|e| err(format!("not UTF-8 text ({e}): not a configuration file")))
}

/// Parses RON text; `origin` names it in errors.
pub fn parse<T: DeserializeOwned>(text: &str, origin: &str) -> Result<T, ConfigError> {
    ron::Options::default().from_str(text).map_err(|e| {
        let field = match &e.code {
            ron::Error::NoSuchStructField { found, .. } => found.clone(),
            ron::Error::MissingStructField { field, .. } => field.to_string(),
            ron::Error::DuplicateStructField { field, .. } => field.to_string(),
            _ => "(syntax)".to_string(),
        };
        ConfigError {
            origin: origin.to_string(),
            line: e.span.start.line,
            column: e.span.start.col,
            field,
            message: e.code.to_string(),
        }
    })
}

/// Builds the error for a semantically invalid field, locating `key` (the last component of the
/// field path) at its `occurrence`-th appearance (0-based) as `key:` in the text.
pub fn invalid(
    text: &str,
    origin: &str,
    field: &str,
    key: &str,
    occurrence: usize,
    message: String,
) -> ConfigError {
    let (line, column) = locate(text, key, occurrence).unwrap_or((0, 0));
    ConfigError { origin: origin.to_string(), line, column, field: field.to_string(), message }
}

/// Checks a file's `version` field against the one version this build reads, locating the
/// field in errors.
pub fn check_version(text: &str, origin: &str, found: u32, supported: u32) -> Result<(), ConfigError> {
    Checker::new(text, origin).version(found, supported)
}

/// 1-based line and column of the `occurrence`-th `key:` (outside comments) in RON text.
pub fn locate(text: &str, key: &str, occurrence: usize) -> Option<(usize, usize)> {
    let mut seen = 0;
    for (i, line) in text.lines().enumerate() {
        let code = line.split("//").next().unwrap_or("");
        let mut from = 0;
        while let Some(pos) = code[from..].find(key) {
            let at = from + pos;
            let before_ok = at == 0 || !is_ident(code.as_bytes()[at - 1]);
            let rest = code[at + key.len()..].trim_start();
            if before_ok && rest.starts_with(':') {
                if seen == occurrence {
                    return Some((i + 1, at + 1));
                }
                seen += 1;
            }
            from = at + key.len();
        }
    }
    None
}

fn is_ident(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_'
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn locate_finds_nth_key_and_skips_comments_and_longer_names() {
        let text = "(\n  // k_n: 3\n  kk_n: 1,\n  k_n: 2,\n  b: (k_n: 4),\n)";
        assert_eq!(locate(text, "k_n", 0), Some((4, 3)));
        assert_eq!(locate(text, "k_n", 1), Some((5, 7)));
        assert_eq!(locate(text, "k_n", 2), None);
    }

    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Small {
        a_m: f64,
    }

    #[test]
    fn an_endless_or_huge_file_is_refused_without_reading_it_all() {
        let e = load_file::<Small>(Path::new("/dev/zero")).unwrap_err();
        assert!(e.message.contains("larger than 4 MiB"), "{e}");
        assert!(e.to_string().starts_with("/dev/zero: "), "{e}");
        let dir = std::env::temp_dir().join(format!("spidar-config-cap-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("big.ron");
        std::fs::write(&p, vec![b' '; 2000]).unwrap();
        assert!(read_capped(&p, 2000).is_ok(), "exactly the cap is read");
        assert!(read_capped(&p, 1999).unwrap_err().message.contains("larger than"));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn unknown_field_is_named_with_its_position() {
        let e = parse::<Small>("(\n  a_m: 1.0,\n  b_m: 2.0,\n)", "x.ron").unwrap_err();
        assert_eq!(e.field, "b_m");
        assert_eq!(e.line, 3);
        assert!(e.to_string().starts_with("x.ron:3:"), "{e}");
    }
}

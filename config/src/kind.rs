//! What a file is, said in the file: every spidar file carries a top-level `kind: "..."` entry,
//! so any file name works and a file given where another kind is expected is refused with an
//! error that names both kinds (not with a misleading "unknown field" from the wrong format).
//!
//! The check reads the `kind` entry before the typed parse, and hands the typed parse the text
//! with that entry blanked out (spaces, same lines and columns), so the file structs need no
//! field for it and every later error keeps its position.

use serde::de::DeserializeOwned;

use crate::ConfigError;

/// The kinds of file spidar reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FileKind {
    /// A rig: string geometry, limits, safety settings, boards (`configs/rig-spidar-h.ron`).
    Rig,
    /// The rig-check world of planes and balls (`configs/scene-walls.ron`).
    WallsScene,
    /// The virtual boxer's parameters (`configs/boxer.ron`).
    Boxer,
    /// A crowd of keyframe characters (`configs/scene-crowd.ron`).
    CrowdScene,
    /// An articulated body (`configs/body-upper.ron`, `configs/body-character.ron`).
    Body,
    /// Bodies placed in a world with floor, gravity and contacts (`configs/scene-boxing.ron`).
    BodyScene,
    /// A multidimensional keyframe set (`configs/keyframes-humanoid.ron`).
    Keyframes,
    /// The simulated user's two hands (`configs/script-example.ron`).
    Script,
    /// A calibration jig's known points (`configs/jig-spidar-h.ron`).
    Jig,
    /// A calibration session's recorded poses (written by `spidar calib record`).
    CalibrationSession,
}

impl FileKind {
    pub const ALL: [FileKind; 10] = [
        FileKind::Rig,
        FileKind::WallsScene,
        FileKind::Boxer,
        FileKind::CrowdScene,
        FileKind::Body,
        FileKind::BodyScene,
        FileKind::Keyframes,
        FileKind::Script,
        FileKind::Jig,
        FileKind::CalibrationSession,
    ];

    /// The value of the `kind` entry.
    pub fn tag(self) -> &'static str {
        match self {
            FileKind::Rig => "rig",
            FileKind::WallsScene => "walls-scene",
            FileKind::Boxer => "boxer",
            FileKind::CrowdScene => "crowd-scene",
            FileKind::Body => "body",
            FileKind::BodyScene => "body-scene",
            FileKind::Keyframes => "keyframes",
            FileKind::Script => "script",
            FileKind::Jig => "jig",
            FileKind::CalibrationSession => "calibration-session",
        }
    }

    /// What such a file is, for messages ("a rig file").
    pub fn what(self) -> &'static str {
        match self {
            FileKind::Rig => "a rig file",
            FileKind::WallsScene => "a walls scene file",
            FileKind::Boxer => "a boxer file",
            FileKind::CrowdScene => "a crowd scene file",
            FileKind::Body => "a body file",
            FileKind::BodyScene => "a body scene file",
            FileKind::Keyframes => "a keyframe set file",
            FileKind::Script => "a script file",
            FileKind::Jig => "a calibration jig file",
            FileKind::CalibrationSession => "a calibration session file",
        }
    }

    pub fn from_tag(tag: &str) -> Option<FileKind> {
        FileKind::ALL.into_iter().find(|k| k.tag() == tag)
    }
}

impl std::fmt::Display for FileKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.tag())
    }
}

/// The top-level `kind: "..."` entry as found in a file.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct KindEntry {
    /// The value as written.
    pub tag: String,
    /// 1-based position of `kind`.
    pub line: usize,
    pub column: usize,
    /// Bytes of the entry: from `kind` to its value's closing quote, and a comma after it.
    pub span: std::ops::Range<usize>,
}

/// Finds the `kind` entry of the outermost struct of RON `text` (comments and strings skipped;
/// fields of nested structs named `kind` are not it). `Err`: a malformed or repeated entry.
pub fn find_kind(text: &str) -> Result<Option<KindEntry>, (usize, usize, String)> {
    let b = text.as_bytes();
    let pos = |i: usize| {
        let before = &text[..i];
        let line = before.matches('\n').count() + 1;
        let column = i - before.rfind('\n').map_or(0, |n| n + 1) + 1;
        (line, column)
    };
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut found: Option<KindEntry> = None;
    let mut depth = 0usize;
    let mut i = 0;
    while i < b.len() {
        let c = b[i];
        if b[i..].starts_with(b"//") {
            i = text[i..].find('\n').map_or(b.len(), |n| i + n);
        } else if b[i..].starts_with(b"/*") {
            // Block comments nest in RON.
            let mut level = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    level += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    level -= 1;
                    i += 2;
                    if level == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if c == b'"' {
            i = skip_string(b, i);
        } else if c == b'r' && (i == 0 || !ident(b[i - 1])) && is_raw_string(&b[i + 1..]) {
            let hashes = b[i + 1..].iter().take_while(|&&h| h == b'#').count();
            let close: Vec<u8> = std::iter::once(b'"').chain(std::iter::repeat_n(b'#', hashes)).collect();
            let body = i + 2 + hashes;
            i = b[body..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(b.len(), |p| body + p + close.len());
        } else if matches!(c, b'(' | b'[' | b'{') {
            depth += 1;
            i += 1;
        } else if matches!(c, b')' | b']' | b'}') {
            depth = depth.saturating_sub(1);
            i += 1;
        } else if depth == 1
            && b[i..].starts_with(b"kind")
            && (i == 0 || !ident(b[i - 1]))
            && !b.get(i + 4).is_some_and(|&n| ident(n))
        {
            let start = i;
            let mut j = skip_blank(b, i + 4);
            if b.get(j) != Some(&b':') {
                i += 4;
                continue;
            }
            j = skip_blank(b, j + 1);
            let (line, column) = pos(start);
            if b.get(j) != Some(&b'"') {
                return Err((
                    line,
                    column,
                    "the kind must be a string in double quotes, e.g. kind: \"rig\"".into(),
                ));
            }
            let end = skip_string(b, j);
            let tag = text[j + 1..end.saturating_sub(1).max(j + 1)].to_string();
            let mut stop = end;
            let after = skip_blank(b, end);
            if b.get(after) == Some(&b',') {
                stop = after + 1;
            }
            if found.is_some() {
                return Err((line, column, "a second kind entry: a file is of one kind".into()));
            }
            found = Some(KindEntry { tag, line, column, span: start..stop });
            i = stop;
        } else {
            i += 1;
        }
    }
    Ok(found)
}

fn is_raw_string(rest: &[u8]) -> bool {
    let hashes = rest.iter().take_while(|&&h| h == b'#').count();
    rest.get(hashes) == Some(&b'"')
}

/// The index just past the string literal starting at `b[i] == '"'`.
fn skip_string(b: &[u8], mut i: usize) -> usize {
    i += 1;
    while i < b.len() {
        match b[i] {
            b'\\' => i += 2,
            b'"' => return i + 1,
            _ => i += 1,
        }
    }
    b.len()
}

/// Skips spaces, tabs and newlines (not comments: a comment inside an entry is not ours to keep).
fn skip_blank(b: &[u8], mut i: usize) -> usize {
    while b.get(i).is_some_and(|c| c.is_ascii_whitespace()) {
        i += 1;
    }
    i
}

fn kind_error(origin: &str, line: usize, column: usize, message: String) -> ConfigError {
    ConfigError { origin: origin.to_string(), line, column, field: "kind".into(), message }
}

/// The kind a file says it is. Errors: no `kind` entry, or one that is not a spidar kind.
pub fn peek_kind(text: &str, origin: &str) -> Result<FileKind, ConfigError> {
    let e = find_kind(text).map_err(|(l, c, m)| kind_error(origin, l, c, m))?;
    let Some(e) = e else {
        return Err(kind_error(
            origin,
            0,
            0,
            format!(
                "the file does not say what it is: spidar files start with a kind entry, e.g. `kind: \"rig\",` \
                 (kinds: {})",
                all_tags()
            ),
        ));
    };
    FileKind::from_tag(&e.tag).ok_or_else(|| {
        kind_error(
            origin,
            e.line,
            e.column,
            format!("\"{}\" is not a kind of spidar file (kinds: {})", e.tag, all_tags()),
        )
    })
}

fn all_tags() -> String {
    FileKind::ALL.iter().map(|k| k.tag()).collect::<Vec<_>>().join(", ")
}

/// Checks that `text` says it is `expected`, and returns the text with the `kind` entry blanked
/// (same lines and columns) for the typed parse.
pub fn expect_kind(text: &str, origin: &str, expected: FileKind) -> Result<String, ConfigError> {
    let entry = find_kind(text).map_err(|(l, c, m)| kind_error(origin, l, c, m))?;
    let Some(entry) = entry else {
        return Err(kind_error(
            origin,
            0,
            0,
            format!(
                "the file does not say what it is: {} starts with `kind: \"{}\",` (add it before `version`)",
                expected.what(),
                expected.tag()
            ),
        ));
    };
    if entry.tag != expected.tag() {
        let found = match FileKind::from_tag(&entry.tag) {
            Some(k) => format!("this is {} (kind \"{}\")", k.what(), k.tag()),
            None => format!("this file says kind \"{}\", which is not a kind of spidar file", entry.tag),
        };
        return Err(kind_error(
            origin,
            entry.line,
            entry.column,
            format!("{found}, not {} (kind \"{}\"): check the path", expected.what(), expected.tag()),
        ));
    }
    let mut blanked = text.as_bytes().to_vec();
    for c in &mut blanked[entry.span] {
        if *c != b'\n' {
            *c = b' ';
        }
    }
    // Only ASCII bytes were replaced by spaces, at whole characters of an ASCII entry.
    Ok(String::from_utf8(blanked).unwrap_or_else(|_| text.to_string()))
}

/// Parses RON text of kind `expected` (see [`expect_kind`]); `origin` names it in errors.
pub fn parse_kind<T: DeserializeOwned>(
    text: &str,
    origin: &str,
    expected: FileKind,
) -> Result<T, ConfigError> {
    let body = expect_kind(text, origin, expected)?;
    crate::parse(&body, origin)
}

/// Puts `kind: "<tag>",` as the first entry of the outermost struct of serialized RON `text`
/// (for writers that serialize a struct).
pub fn with_kind(text: &str, kind: FileKind) -> String {
    match text.find('(') {
        Some(open) => {
            let (head, tail) = text.split_at(open + 1);
            let indent = if tail.starts_with('\n') { "\n    " } else { " " };
            format!("{head}{indent}kind: \"{}\",{tail}", kind.tag())
        }
        None => text.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(serde::Deserialize, Debug)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Small {
        version: u32,
        a_m: f64,
    }

    const SMALL: &str = "// a file\n(\n    kind: \"rig\",\n    version: 1,\n    a_m: 2.0,\n)\n";

    #[test]
    fn the_kind_is_found_at_the_top_level_only() {
        let e = find_kind(SMALL).unwrap().unwrap();
        assert_eq!((e.tag.as_str(), e.line, e.column), ("rig", 3, 5));
        assert_eq!(&SMALL[e.span], "kind: \"rig\",");
        // Nested fields named kind, comments and strings are not the file's kind.
        let nested = "(\n  // kind: \"jig\"\n  name: \"kind: x\",\n  joint: (kind: Free),\n  r: r#\"kind: \"a\"\"#,\n)";
        assert_eq!(find_kind(nested).unwrap(), None);
        assert!(find_kind("(kind: \"rig\", kind: \"jig\")").is_err());
        assert!(find_kind("(kind: rig)").is_err());
        assert_eq!(find_kind("(kinds: 1, kind_x: 2)").unwrap(), None);
    }

    #[test]
    fn a_file_of_the_right_kind_parses_with_every_position_kept() {
        let s: Small = parse_kind(SMALL, "s.ron", FileKind::Rig).unwrap();
        assert_eq!(s.a_m, 2.0);
        let bad = SMALL.replace("a_m: 2.0", "b_m: 2.0");
        let e = parse_kind::<Small>(&bad, "s.ron", FileKind::Rig).unwrap_err();
        assert_eq!((e.line, e.field.as_str()), (5, "b_m"), "{e}");
    }

    #[test]
    fn a_wrong_kind_is_refused_naming_both_kinds_at_the_entry() {
        let text = SMALL.replace("\"rig\"", "\"boxer\"");
        let e = parse_kind::<Small>(&text, "x.ron", FileKind::WallsScene).unwrap_err();
        let m = e.to_string();
        assert!(m.starts_with("x.ron:3:5: kind: "), "{m}");
        assert!(m.contains("a boxer file (kind \"boxer\")"), "{m}");
        assert!(m.contains("not a walls scene file (kind \"walls-scene\")"), "{m}");
        let unknown = SMALL.replace("\"rig\"", "\"banana\"");
        let m = parse_kind::<Small>(&unknown, "x.ron", FileKind::Rig).unwrap_err().to_string();
        assert!(m.contains("\"banana\"") && m.contains("a rig file (kind \"rig\")"), "{m}");
        let m = peek_kind(&unknown, "x.ron").unwrap_err().to_string();
        assert!(m.contains("not a kind of spidar file"), "{m}");
    }

    #[test]
    fn a_file_without_kind_is_told_what_to_add() {
        let text = SMALL.replace("    kind: \"rig\",\n", "");
        let m = parse_kind::<Small>(&text, "x.ron", FileKind::Rig).unwrap_err().to_string();
        assert!(m.contains("`kind: \"rig\",`"), "{m}");
        assert!(peek_kind(&text, "x.ron").is_err());
    }

    #[test]
    fn with_kind_makes_a_file_that_parses_as_that_kind() {
        let out = with_kind("(\n    version: 1,\n    a_m: 3.0,\n)", FileKind::Jig);
        assert_eq!(peek_kind(&out, "o").unwrap(), FileKind::Jig);
        let s: Small = parse_kind(&out, "o", FileKind::Jig).unwrap();
        assert_eq!(s.a_m, 3.0);
        let one_line = with_kind("(version: 1, a_m: 4.0)", FileKind::Script);
        assert_eq!(peek_kind(&one_line, "o").unwrap(), FileKind::Script);
    }

    #[test]
    fn every_kind_has_its_own_tag() {
        for k in FileKind::ALL {
            assert_eq!(FileKind::from_tag(k.tag()), Some(k));
            assert_eq!(FileKind::ALL.iter().filter(|o| o.tag() == k.tag()).count(), 1);
        }
    }
}

/// Reads a file of kind `expected` and parses it: the value and the file's text.
pub fn load_file_kind<T: DeserializeOwned>(
    path: &std::path::Path,
    expected: FileKind,
) -> Result<(T, String), ConfigError> {
    // Read through `load_file` (its limits and messages); any RON is taken before the kind check.
    let (_, text) = crate::load_file::<serde::de::IgnoredAny>(path)?;
    let value = parse_kind(&text, &path.display().to_string(), expected)?;
    Ok((value, text))
}

#[cfg(test)]
mod file_tests {
    use super::*;

    #[test]
    fn a_file_is_read_then_checked_for_its_kind() {
        let dir = std::env::temp_dir().join(format!("spidar-config-kind-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("any-name.txt");
        std::fs::write(&p, "(kind: \"jig\", version: 1)").unwrap();
        #[derive(serde::Deserialize)]
        #[serde(deny_unknown_fields)]
        struct V {
            version: u32,
        }
        let (v, text): (V, String) = load_file_kind(&p, FileKind::Jig).unwrap();
        assert_eq!(v.version, 1);
        assert!(text.contains("\"jig\""));
        let e = load_file_kind::<V>(&p, FileKind::Rig).err().unwrap().to_string();
        assert!(e.contains("a calibration jig file (kind \"jig\")") && e.contains("not a rig file"), "{e}");
        std::fs::write(&p, "(kind: \"jig\", version: 1").unwrap();
        assert!(load_file_kind::<V>(&p, FileKind::Jig).is_err(), "a syntax error is still one");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

//! Located checks: the one way every file spidar reads checks its values after parsing. A check
//! takes where the value sits ([`At`]: its dotted path and which `key:` in the text holds it) and
//! what it must be (finite, positive, a whole number of items, or inside a [`Bound`] with the
//! reason for that bound), and fails with a [`ConfigError`] that names the file, line, column,
//! field, the value and what to do.
//!
//! Why it exists: the rig file, the keyframe sets, the bodies and the boxer file each wrote the
//! same "if not in range, build an error with its position" by hand, dozens of times, with
//! reasons sometimes given and sometimes not. What it must never do: accept a NaN (every range
//! test is written so that NaN fails), or let a hard limit be overridden.

use crate::{invalid, ConfigError};

/// Where a value sits in a file: the dotted path shown to a person, and the `key:` in the text
/// (with which of its appearances, 0-based) that locates its line and column.
#[derive(Clone, Debug, PartialEq)]
pub struct At {
    /// Dotted path of the field, e.g. `hands[1].strings[2].anchor_m`.
    pub field: String,
    /// The key as written in the file (the last part of the path).
    pub key: &'static str,
    /// Which appearance of `key:` in the text holds this value.
    pub occurrence: usize,
}

impl At {
    /// A top-level field, written once in the file: the path is the key.
    pub fn key(key: &'static str) -> At {
        At { field: key.to_string(), key, occurrence: 0 }
    }

    /// A field with a path of its own, at the `occurrence`-th `key:` of the text.
    pub fn new(field: impl Into<String>, key: &'static str, occurrence: usize) -> At {
        At { field: field.into(), key, occurrence }
    }
}

/// Whether a bound may be exceeded by naming its key in the file's `overrides`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Limit {
    /// Beyond it the rule itself is meaningless (a fade of `-0.0` never fades): never overridable.
    Hard,
    /// A fact of the hardware or of the physics: a file may go beyond it only by naming the key in
    /// its `overrides`, and the run shows every override in effect.
    Physical,
}

/// A closed range a value must lie in, with its unit and the reason, for messages a person can
/// act on. NaN lies in no range.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bound {
    /// The key an `overrides` list names to go beyond a physical bound.
    pub key: &'static str,
    pub lo: f64,
    pub hi: f64,
    /// Unit for messages ("N", "m", "s"; empty for a pure number).
    pub unit: &'static str,
    /// Why the bound is where it is.
    pub why: &'static str,
    pub limit: Limit,
}

impl Bound {
    /// A bound never overridden.
    pub const fn hard(key: &'static str, lo: f64, hi: f64, unit: &'static str, why: &'static str) -> Bound {
        Bound { key, lo, hi, unit, why, limit: Limit::Hard }
    }

    /// A bound a file may exceed by naming `key` in its `overrides`.
    pub const fn physical(
        key: &'static str,
        lo: f64,
        hi: f64,
        unit: &'static str,
        why: &'static str,
    ) -> Bound {
        Bound { key, lo, hi, unit, why, limit: Limit::Physical }
    }

    /// The same bound with other ends (ends that depend on another value, e.g. the tick period).
    pub const fn between(self, lo: f64, hi: f64) -> Bound {
        Bound { lo, hi, ..self }
    }

    /// True when `v` lies in `lo ..= hi` (false for NaN).
    pub fn holds(&self, v: f64) -> bool {
        v >= self.lo && v <= self.hi
    }

    fn range(&self) -> String {
        let u = if self.unit.is_empty() { String::new() } else { format!(" {}", self.unit) };
        format!("{} .. {}{u}", self.lo, self.hi)
    }
}

/// Checks the values of one file's text: every failure is located in that text.
#[derive(Clone, Copy, Debug)]
pub struct Checker<'a> {
    text: &'a str,
    origin: &'a str,
    overrides: &'a [String],
}

impl<'a> Checker<'a> {
    /// Checks for the file `origin` whose text is `text`, with no overrides.
    pub fn new(text: &'a str, origin: &'a str) -> Checker<'a> {
        Checker { text, origin, overrides: &[] }
    }

    /// The same checker honouring the file's `overrides` for physical bounds.
    pub fn with_overrides(self, overrides: &'a [String]) -> Checker<'a> {
        Checker { overrides, ..self }
    }

    /// True when the file overrides the physical bound named `key`.
    pub fn overridden(&self, key: &str) -> bool {
        self.overrides.iter().any(|o| o == key)
    }

    /// The error for the value at `at`: file, line, column, field and `message`.
    pub fn error(&self, at: &At, message: impl Into<String>) -> ConfigError {
        invalid(self.text, self.origin, &at.field, at.key, at.occurrence, message.into())
    }

    /// Fails at `at` with `message` unless `ok`.
    pub fn ensure(&self, ok: bool, at: &At, message: impl FnOnce() -> String) -> Result<(), ConfigError> {
        if ok {
            Ok(())
        } else {
            Err(self.error(at, message()))
        }
    }

    /// `v` must be a finite number.
    pub fn finite(&self, at: &At, v: f64) -> Result<f64, ConfigError> {
        self.ensure(v.is_finite(), at, || format!("{v}: must be a finite number"))?;
        Ok(v)
    }

    /// Every component of `v` must be finite, and at most `max_abs` in size.
    pub fn finite_within(&self, at: &At, v: &[f64], max_abs: f64, unit: &str) -> Result<(), ConfigError> {
        let ok = v.iter().all(|c| c.is_finite() && c.abs() <= max_abs);
        self.ensure(ok, at, || format!("{v:?}: must be finite numbers within {max_abs} {unit}"))
    }

    /// `v` must be finite and greater than zero; `why` says what a zero or negative value breaks.
    pub fn positive(&self, at: &At, v: f64, unit: &str, why: &str) -> Result<f64, ConfigError> {
        self.ensure(v.is_finite() && v > 0.0, at, || {
            let u = if unit.is_empty() { String::new() } else { format!(" {unit}") };
            format!("{v}{u}: must be a positive number ({why})")
        })?;
        Ok(v)
    }

    /// `v` must lie in `bound`; a physical bound may be exceeded when the file overrides its key.
    pub fn within(&self, at: &At, v: f64, bound: &Bound) -> Result<f64, ConfigError> {
        if bound.holds(v) {
            return Ok(v);
        }
        let u = if bound.unit.is_empty() { String::new() } else { format!(" {}", bound.unit) };
        let message = match bound.limit {
            Limit::Hard => format!("{v}{u}: must be in {} because {}", bound.range(), bound.why),
            Limit::Physical if self.overridden(bound.key) => return Ok(v),
            Limit::Physical => format!(
                "{v}{u}: outside the safe range {} because {}; fix the value, or list \"{}\" in overrides to \
                 accept it (the run summary will show it)",
                bound.range(),
                bound.why,
                bound.key
            ),
        };
        Err(self.error(at, message))
    }

    /// A list must hold `lo ..= hi` items.
    pub fn count(&self, at: &At, n: usize, lo: usize, hi: usize, items: &str) -> Result<(), ConfigError> {
        let need = if lo == hi { format!("{lo}") } else { format!("{lo} to {hi}") };
        self.ensure((lo..=hi).contains(&n), at, || format!("needs {need} {items}, got {n}"))
    }

    /// The file's `version` must be the one this build reads.
    pub fn version(&self, found: u32, supported: u32) -> Result<(), ConfigError> {
        self.ensure(found == supported, &At::key("version"), || {
            format!("version {found} is not supported; this build reads version {supported}")
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "(\n  version: 1,\n  a_m: 2.0,\n  list: [(b_n: 1.0), (b_n: -1.0)],\n)";

    #[test]
    fn a_failed_check_names_the_line_column_and_field_of_the_value() {
        let c = Checker::new(TEXT, "f.ron");
        let e = c.positive(&At::new("list[1].b_n", "b_n", 1), -1.0, "N", "a string pulls").unwrap_err();
        assert_eq!((e.line, e.column, e.field.as_str()), (4, 23, "list[1].b_n"));
        assert_eq!(
            e.to_string(),
            "f.ron:4:23: list[1].b_n: -1 N: must be a positive number (a string pulls)"
        );
        assert!(c.positive(&At::new("list[0].b_n", "b_n", 0), 1.0, "N", "x").is_ok());
    }

    #[test]
    fn nan_and_infinities_fail_every_check() {
        let c = Checker::new(TEXT, "f.ron");
        let at = At::key("a_m");
        let b = Bound::hard("a_m", f64::NEG_INFINITY, f64::INFINITY, "m", "any");
        for v in [f64::NAN, -f64::NAN] {
            assert!(c.within(&at, v, &b).is_err(), "{v} is in no range");
            assert!(c.positive(&at, v, "m", "x").is_err());
            assert!(c.finite(&at, v).is_err());
        }
        for v in [f64::INFINITY, f64::NEG_INFINITY] {
            assert!(c.finite(&at, v).is_err() && c.positive(&at, v, "m", "x").is_err());
            assert!(c.finite_within(&at, &[0.0, v], 1e300, "m").is_err());
        }
        assert!(c.positive(&at, f64::from_bits(1), "m", "x").is_ok(), "a subnormal is positive");
        assert!(c.positive(&at, -0.0, "m", "x").is_err(), "-0.0 is not positive");
    }

    #[test]
    fn a_physical_bound_yields_to_an_override_and_a_hard_one_never() {
        let physical = Bound::physical("a_m", 0.0, 1.0, "m", "a reason");
        let hard = Bound::hard("a_m", 0.0, 1.0, "m", "a reason");
        let plain = Checker::new(TEXT, "f.ron");
        let e = plain.within(&At::key("a_m"), 2.0, &physical).unwrap_err();
        assert_eq!(e.line, 3);
        assert!(
            e.message.contains("0 .. 1 m because a reason") && e.message.contains("\"a_m\" in overrides"),
            "{e}"
        );
        let over = ["a_m".to_string()];
        let lenient = plain.with_overrides(&over);
        assert_eq!(lenient.within(&At::key("a_m"), 2.0, &physical).unwrap(), 2.0);
        let e = lenient.within(&At::key("a_m"), 2.0, &hard).unwrap_err();
        assert!(e.message.contains("must be in 0 .. 1 m because a reason"), "{e}");
        assert!(plain.within(&At::key("a_m"), 1.0, &hard.between(0.0, 0.5)).is_err());
    }

    #[test]
    fn counts_and_versions_say_what_is_needed() {
        let c = Checker::new(TEXT, "f.ron");
        let e = c.count(&At::key("list"), 2, 4, 4, "strings").unwrap_err();
        assert_eq!((e.line, e.message.as_str()), (4, "needs 4 strings, got 2"));
        assert!(c.count(&At::key("list"), 2, 1, 3, "items").is_ok());
        let e = c.version(2, 1).unwrap_err();
        assert_eq!((e.line, e.field.as_str()), (2, "version"));
        assert!(e.message.contains("this build reads version 1"));
    }
}

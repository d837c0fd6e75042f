//! One summary, two renderings: a [`Summary`] is built once, line by line, each line with the
//! figures scripts get for it, and is printed as text for a person (`Display`) or as JSON for
//! scripts ([`Summary::json`]). The lines every summary of the loop shares (lateness, compute,
//! forces, safety counters, how the loop ended) are built here, from [`Stats`] and [`Counters`],
//! so a live run, a virtual run and a recording say them the same way.
//!
//! Why it exists: the session summary was rendered five ways (text and JSON of the live and the
//! virtual run, the recording's text), each repeating the same lines. What it must never do: run
//! in the tick (it allocates), or print a figure in the text that the JSON does not carry.

use std::fmt;

use serde_json::{json, Map, Value};

use crate::telemetry::{Percentiles, Stats};
use crate::{Counters, Lifecycle};

/// A summary for a person and for scripts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Summary {
    heading: String,
    /// Text lines: a label (empty: the line continues the one above; none: the text as it is)
    /// and the text.
    lines: Vec<(Option<&'static str>, String)>,
    json: Map<String, Value>,
}

impl Summary {
    /// A summary whose first line is `heading`.
    pub fn new(heading: impl Into<String>) -> Summary {
        Summary { heading: heading.into(), ..Summary::default() }
    }

    /// A line of text under `label`; an empty label continues the line above.
    pub fn line(&mut self, label: &'static str, text: impl Into<String>) -> &mut Summary {
        self.lines.push((Some(label), text.into()));
        self
    }

    /// A line of text printed as it is, without a label's column (a list under a line).
    pub fn raw_line(&mut self, text: impl Into<String>) -> &mut Summary {
        self.lines.push((None, text.into()));
        self
    }

    /// A figure for scripts under `key`.
    pub fn field(&mut self, key: &str, value: impl Into<Value>) -> &mut Summary {
        self.json.insert(key.to_string(), value.into());
        self
    }

    /// A line of text and the field that carries its figures.
    pub fn row(
        &mut self,
        label: &'static str,
        text: impl Into<String>,
        key: &str,
        value: impl Into<Value>,
    ) -> &mut Summary {
        self.line(label, text).field(key, value)
    }

    /// The figures, as one JSON object.
    pub fn json(&self) -> Value {
        Value::Object(self.json.clone())
    }

    /// The text of the first line under `label`, if any (for tests and tools).
    pub fn text_of(&self, label: &str) -> Option<&str> {
        self.lines.iter().find(|(l, _)| *l == Some(label)).map(|(_, t)| t.as_str())
    }
}

impl fmt::Display for Summary {
    /// The heading, then `  label        text` per line (labels in a column of 12).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.heading)?;
        for (label, text) in &self.lines {
            match label {
                Some(label) => write!(f, "\n  {label:<12} {text}")?,
                None => write!(f, "\n{text}")?,
            }
        }
        Ok(())
    }
}

/// Percentiles as scripts get them (seconds).
pub fn percentiles_json(p: &Percentiles) -> Value {
    json!({ "count": p.count, "p50": p.p50_s, "p99": p.p99_s, "p999": p.p999_s, "max": p.max_s })
}

/// The lowest tension commanded (0 when no tick commanded any).
fn min_tension_n(s: &Stats) -> f64 {
    if s.min_tension_n.is_finite() {
        s.min_tension_n
    } else {
        0.0
    }
}

/// `lateness` and `misses`: how late the loop woke.
pub fn lateness(out: &mut Summary, s: &Stats, misses: u64) {
    let lat = s.lateness.percentiles();
    out.row("lateness", lat.to_string(), "lateness_s", percentiles_json(&lat));
    out.row("misses", format!("{misses} ticks woke > 1 ms late"), "misses", misses);
}

/// `compute`: the tick's own time; `note` follows the figures in the text.
pub fn compute(out: &mut Summary, s: &Stats, note: &str) {
    let comp = s.compute.percentiles();
    out.row("compute", format!("{comp}{note}"), "compute_s", percentiles_json(&comp));
}

/// `max force` (and `tensions` when `tensions`): the largest force per hand and the tension range.
pub fn forces(out: &mut Summary, s: &Stats, tensions: bool) {
    let [left, right] = s.max_force_n;
    out.line("max force", format!("left {left:.2} N, right {right:.2} N"));
    if tensions {
        out.line("tensions", format!("{:.2} .. {:.2} N commanded", min_tension_n(s), s.max_tension_n));
    }
    let tension = json!({ "min": min_tension_n(s), "max": s.max_tension_n });
    out.field("forces", json!({ "max_force_n": s.max_force_n, "tension_n": tension }));
}

/// The safety counters for scripts (the text says them in the run's own lines).
pub fn safety_json(c: &Counters) -> Value {
    json!({
        "clamped_ticks": c.clamped,
        "infeasible_ticks": c.infeasible,
        "fallback_ticks": c.fallback,
        "produced_limited_ticks": c.produced_limited,
        "produced_unmet_ticks": c.produced_unmet,
        "stiffness_limited_ticks": c.stiffness_limited,
        "stale_model_ticks": c.stale,
        "non_finite_forces": c.non_finite,
        "faults": c.faults,
        "device_errors": c.device_errors,
        "reopens": c.reopens,
        "held_ticks": c.held,
        "late_replies": c.late_replies,
        "count_jumps": c.count_jumps,
        "residual_high": c.residual_high,
        "rehomes": c.rehomes,
    })
}

/// The start of every `safety` line: ticks per hand (left/right) the force was clamped to the
/// hand's limit, could not be rendered in full, needed the box-QP fallback, or whose tensions
/// produced more than the limit and were scaled down to it (`produced`; `unmet` when even the
/// minimum tensions were above it, said only when it happened).
pub fn clamped_counts(c: &Counters) -> String {
    let unmet = if c.produced_unmet == [0, 0] {
        String::new()
    } else {
        format!(" ({}/{} UNMET: minimum tensions above the limit)", c.produced_unmet[0], c.produced_unmet[1])
    };
    format!(
        "clamped {}/{}, infeasible {}/{}, fallback {}/{}, produced-limited {}/{}{unmet}",
        c.clamped[0],
        c.clamped[1],
        c.infeasible[0],
        c.infeasible[1],
        c.fallback[0],
        c.fallback[1],
        c.produced_limited[0],
        c.produced_limited[1]
    )
}

/// The line continuing `safety`: the ticks that held the last safe output (a late, missing or
/// rejected reply) and why.
pub fn held(out: &mut Summary, c: &Counters) {
    out.line(
        "",
        format!(
            "held ticks {}/{} (late replies {}, count jumps {}/{}, residual high {}/{}), rehomes {}",
            c.held[0],
            c.held[1],
            c.late_replies,
            c.count_jumps[0],
            c.count_jumps[1],
            c.residual_high[0],
            c.residual_high[1],
            c.rehomes
        ),
    );
}

/// `end`: the final state, how the loop stopped and on how many signals.
pub fn end(out: &mut Summary, state: Lifecycle, clean_stop: bool, halted: bool, signals: u32) {
    let by = match signals {
        0 => String::new(),
        1 => ", on a stop signal".into(),
        n => format!(", on {n} stop signals"),
    };
    let how = match (clean_stop, halted) {
        (true, false) => "forces ramped out, strings at minimum tension, device off",
        (true, true) => "stopped at once: outputs zeroed without the ramp-out, device off",
        (false, _) => "NOT a clean stop",
    };
    let figures =
        json!({ "state": state.name(), "clean_stop": clean_stop, "halted": halted, "stop_signals": signals });
    out.row("end", format!("{} ({how}{by})", state.name()), "end", figures);
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_line_prints_under_its_label_and_each_figure_goes_to_the_json() {
        let mut s = Summary::new("spidar run: test");
        s.row("ticks", "10 active", "active_ticks", 10)
            .line("", "more")
            .field("only_json", "x")
            .raw_line("    as is");
        end(&mut s, Lifecycle::Inactive, true, false, 2);
        assert_eq!(
            s.to_string(),
            "spidar run: test\n  ticks        10 active\n               more\n    as is\n  end          inactive (forces ramped \
             out, strings at minimum tension, device off, on 2 stop signals)"
        );
        let j = s.json();
        assert_eq!(j["active_ticks"], 10);
        assert_eq!(j["only_json"], "x");
        assert_eq!(j["end"]["stop_signals"], 2);
        assert_eq!(j["end"]["clean_stop"], true);
        assert_eq!(s.text_of("ticks"), Some("10 active"));
    }

    #[test]
    fn the_produced_force_counters_are_in_the_safety_text_and_json() {
        let mut c = Counters { produced_limited: [3, 7], ..Counters::default() };
        assert!(clamped_counts(&c).ends_with("fallback 0/0, produced-limited 3/7"), "{}", clamped_counts(&c));
        c.produced_unmet = [0, 2];
        assert!(clamped_counts(&c)
            .ends_with("produced-limited 3/7 (0/2 UNMET: minimum tensions above the limit)"));
        let j = safety_json(&c);
        assert_eq!(j["produced_limited_ticks"], json!([3, 7]));
        assert_eq!(j["produced_unmet_ticks"], json!([0, 2]));
    }

    #[test]
    fn a_stop_that_was_not_clean_says_so() {
        let mut s = Summary::new("h");
        end(&mut s, Lifecycle::Faulted, false, true, 0);
        assert_eq!(s.text_of("end"), Some("faulted (NOT a clean stop)"));
    }
}

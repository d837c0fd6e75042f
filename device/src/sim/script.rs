//! Scripts: where the simulated user wants their hand to be, as a function of time.
//!
//! A [`Script`] is a list of [`Segment`]s played in sequence (optionally repeating). Each
//! segment starts from wherever the previous one ended (the first from the hand's start
//! position), so scripts compose without jumps, except where a segment says otherwise
//! (a recorded trajectory is played at its recorded positions).
//!
//! Evaluation goes through a [`ScriptCursor`], which remembers which segment is playing and the
//! state of the lazily generated sparring moves. Moving the cursor forward in time never
//! allocates and never panics, so the rig can evaluate scripts inside `exchange`; moving it
//! backwards replays the script from its start (deterministic, just slower).

use std::f64::consts::TAU;
use std::path::{Path, PathBuf};

use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use serde::Deserialize;

use super::SimRigError;

/// The scripted target at one instant.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Target {
    pub pos_m: DVec3,
    pub vel_m_per_s: DVec3,
}

/// One piece of a script. Positions are in the rig frame.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub enum Segment {
    /// Jump the target to `at_m` and keep it there for `for_s` (a `Reach` first if the jump
    /// matters).
    Hold { at_m: [f64; 3], for_s: f64 },
    /// Minimum-jerk move from where the previous segment ended to `to_m`.
    Reach { to_m: [f64; 3], duration_s: f64 },
    /// Minimum-jerk move out to `to_m` in `out_s`, then back to the start in `back_s`.
    Jab { to_m: [f64; 3], out_s: f64, back_s: f64 },
    /// `turns` turns of a circle of `radius_m` around `centre_m` in the plane normal to
    /// `normal`, one turn per `period_s`, counter-clockwise seen from the tip of `normal`.
    ///
    /// The circle starts at the point of the circle nearest to where the previous segment
    /// ended (when that point projects onto the centre: the direction of +x projected onto the
    /// plane, or +y if +x is along the normal). If the target is not already there (within
    /// 1 mm), a minimum-jerk approach of `period_s / 4` comes first. The circle runs at
    /// constant angular speed, so the target velocity steps at its start and end.
    Circle { centre_m: [f64; 3], radius_m: f64, normal: [f64; 3], period_s: f64, turns: f64 },
    /// A recorded trajectory: CSV with header `t_s,x_m,y_m,z_m`, times relative to the start
    /// of the segment, strictly increasing, the first >= 0. Played at its recorded positions
    /// (holding the first sample before its time), linearly interpolated. Loaded when the
    /// script is prepared (relative paths against the script file's folder, or the current
    /// directory for scripts not read from a file) and replaced by [`Segment::Recorded`].
    Trajectory { file: String },
    /// Random sparring inside the box `centre_m +- half_extent_m` for `for_s`: a stream of
    /// jabs (fast min-jerk out and back, 0.15-0.35 s out, toward -z, the front), guard shifts
    /// (slower min-jerk reaches, 0.4-0.9 s) and short holds (0.1-0.5 s), deterministic for
    /// `seed`. The first move is a guard shift from wherever the target was into the box;
    /// after it the target never leaves the box. The segment ends after `for_s` wherever the
    /// current move has got to.
    Spar { seed: u64, centre_m: [f64; 3], half_extent_m: [f64; 3], for_s: f64 },
    /// A loaded trajectory (from [`Segment::Trajectory`] or [`Segment::recorded`]); cannot be
    /// written in a script file.
    #[serde(skip)]
    Recorded(Recorded),
}

/// One sample of a recorded trajectory.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrajectorySample {
    pub t_s: f64,
    pub pos_m: DVec3,
}

/// A validated recorded trajectory (see [`Segment::Trajectory`]).
#[derive(Clone, Debug, PartialEq)]
pub struct Recorded {
    /// File it came from, or a name given by the caller; used in messages.
    pub origin: String,
    samples: Vec<TrajectorySample>,
}

impl Recorded {
    pub fn samples(&self) -> &[TrajectorySample] {
        &self.samples
    }

    fn duration_s(&self) -> f64 {
        self.samples.last().map_or(0.0, |s| s.t_s)
    }

    fn eval(&self, t: f64) -> Target {
        let s = &self.samples;
        let (Some(first), Some(last)) = (s.first(), s.last()) else {
            return Target::default();
        };
        if t <= first.t_s {
            return Target { pos_m: first.pos_m, vel_m_per_s: DVec3::ZERO };
        }
        if t >= last.t_s {
            return Target { pos_m: last.pos_m, vel_m_per_s: DVec3::ZERO };
        }
        // First sample strictly after t; both neighbours exist because first.t_s < t < last.t_s.
        let i = s.partition_point(|x| x.t_s <= t).clamp(1, s.len() - 1);
        let (a, b) = (s[i - 1], s[i]);
        let dt = b.t_s - a.t_s;
        let vel = (b.pos_m - a.pos_m) / dt;
        Target { pos_m: a.pos_m + vel * (t - a.t_s), vel_m_per_s: vel }
    }
}

impl Segment {
    /// A recorded trajectory from samples in memory (tests, generated motions). `origin` names
    /// it in error messages.
    pub fn recorded(origin: &str, samples: Vec<TrajectorySample>) -> Result<Segment, SimRigError> {
        for (i, s) in samples.iter().enumerate() {
            // Report sample numbers from 1, as a CSV line number would be (minus the header).
            let problem = sample_problem(s, i.checked_sub(1).map(|j| samples[j].t_s));
            if let Some(problem) = problem {
                return Err(SimRigError::Trajectory { file: origin.to_owned(), line: i + 1, problem });
            }
        }
        if samples.is_empty() {
            return Err(SimRigError::Trajectory {
                file: origin.to_owned(),
                line: 0,
                problem: "no samples: a trajectory needs at least one".to_owned(),
            });
        }
        Ok(Segment::Recorded(Recorded { origin: origin.to_owned(), samples }))
    }

    /// Parses trajectory CSV text (header `t_s,x_m,y_m,z_m`); `origin` names it in messages.
    pub fn recorded_from_csv(origin: &str, text: &str) -> Result<Segment, SimRigError> {
        let err =
            |line: usize, problem: String| SimRigError::Trajectory { file: origin.to_owned(), line, problem };
        let mut samples = Vec::new();
        let mut header_seen = false;
        for (i, raw) in text.lines().enumerate() {
            let line_no = i + 1;
            let line = raw.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            if !header_seen {
                let cols: Vec<&str> = line.split(',').map(str::trim).collect();
                if cols != ["t_s", "x_m", "y_m", "z_m"] {
                    return Err(err(
                        line_no,
                        format!("header is `{line}`; expected `t_s,x_m,y_m,z_m` (seconds and metres)"),
                    ));
                }
                header_seen = true;
                continue;
            }
            let mut vals = [0.0; 4];
            let mut n = 0;
            for (k, field) in line.split(',').enumerate() {
                if k >= 4 {
                    n = 5;
                    break;
                }
                let field = field.trim();
                vals[k] = field.parse::<f64>().map_err(|_| {
                    err(
                        line_no,
                        format!("column {} is `{field}`, not a number", ["t_s", "x_m", "y_m", "z_m"][k]),
                    )
                })?;
                n = k + 1;
            }
            if n != 4 {
                return Err(err(line_no, format!("`{line}` has the wrong number of columns; expected 4")));
            }
            let sample = TrajectorySample { t_s: vals[0], pos_m: DVec3::new(vals[1], vals[2], vals[3]) };
            if let Some(problem) = sample_problem(&sample, samples.last().map(|s: &TrajectorySample| s.t_s)) {
                return Err(err(line_no, problem));
            }
            samples.push(sample);
        }
        if !header_seen {
            return Err(err(0, "empty file; expected a header `t_s,x_m,y_m,z_m` and samples".to_owned()));
        }
        if samples.is_empty() {
            return Err(err(0, "no samples after the header; a trajectory needs at least one".to_owned()));
        }
        Ok(Segment::Recorded(Recorded { origin: origin.to_owned(), samples }))
    }

    /// Reads a trajectory CSV file.
    pub fn recorded_from_file(path: &Path) -> Result<Segment, SimRigError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimRigError::Io {
            file: path.display().to_string(),
            what: "the trajectory file",
            source,
        })?;
        Segment::recorded_from_csv(&path.display().to_string(), &text)
    }

    /// Length in time; `None` for a segment that needs preparing first (`Trajectory`).
    pub fn duration_s(&self, from: DVec3) -> Option<f64> {
        Some(match self {
            Segment::Hold { for_s, .. } => *for_s,
            Segment::Reach { duration_s, .. } => *duration_s,
            Segment::Jab { out_s, back_s, .. } => out_s + back_s,
            Segment::Circle { .. } => {
                let c = CircleGeom::new(self, from);
                c.approach_s + c.turns * c.period_s
            }
            Segment::Trajectory { .. } => return None,
            Segment::Spar { for_s, .. } => *for_s,
            Segment::Recorded(r) => r.duration_s(),
        })
    }

    /// Checks numbers and shapes; `what` names the script in messages.
    fn validate(&self, what: &str, index: usize) -> Result<(), SimRigError> {
        let bad =
            |problem: String| SimRigError::InvalidScript { script: what.to_owned(), segment: index, problem };
        let finite3 = |name: &str, v: &[f64; 3]| {
            if v.iter().all(|x| x.is_finite()) {
                Ok(())
            } else {
                Err(bad(format!("{name} = {v:?} is not finite")))
            }
        };
        let positive = |name: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(bad(format!("{name} = {v} must be a finite number > 0")))
            }
        };
        let non_negative = |name: &str, v: f64| {
            if v.is_finite() && v >= 0.0 {
                Ok(())
            } else {
                Err(bad(format!("{name} = {v} must be a finite number >= 0")))
            }
        };
        match self {
            Segment::Hold { at_m, for_s } => {
                finite3("at_m", at_m)?;
                non_negative("for_s", *for_s)
            }
            Segment::Reach { to_m, duration_s } => {
                finite3("to_m", to_m)?;
                positive("duration_s", *duration_s)
            }
            Segment::Jab { to_m, out_s, back_s } => {
                finite3("to_m", to_m)?;
                positive("out_s", *out_s)?;
                positive("back_s", *back_s)
            }
            Segment::Circle { centre_m, radius_m, normal, period_s, turns } => {
                finite3("centre_m", centre_m)?;
                finite3("normal", normal)?;
                if DVec3::from(*normal).length() < 1e-9 {
                    return Err(
                        bad("normal is zero: give the direction the circle's plane faces".to_owned()),
                    );
                }
                non_negative("radius_m", *radius_m)?;
                positive("period_s", *period_s)?;
                non_negative("turns", *turns)
            }
            Segment::Trajectory { file } => Err(bad(format!(
                "trajectory `{file}` was not loaded (internal: prepare the script before validating)"
            ))),
            Segment::Spar { centre_m, half_extent_m, for_s, .. } => {
                finite3("centre_m", centre_m)?;
                finite3("half_extent_m", half_extent_m)?;
                if half_extent_m.iter().any(|h| *h < 0.0) {
                    return Err(bad(format!("half_extent_m = {half_extent_m:?} must be >= 0 on every axis")));
                }
                non_negative("for_s", *for_s)
            }
            Segment::Recorded(_) => Ok(()),
        }
    }
}

fn sample_problem(s: &TrajectorySample, prev_t: Option<f64>) -> Option<String> {
    if !s.t_s.is_finite() || !s.pos_m.is_finite() {
        return Some("sample is not finite (nan or inf)".to_owned());
    }
    match prev_t {
        None if s.t_s < 0.0 => {
            Some(format!("t_s = {} is negative; times are relative to the segment start", s.t_s))
        }
        Some(p) if s.t_s <= p => {
            Some(format!("t_s = {} is not after the previous sample's {p}; times must increase", s.t_s))
        }
        _ => None,
    }
}

/// A simulated user's plan for one hand: segments played in order, optionally forever.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Script {
    pub segments: Vec<Segment>,
    /// Start again from the first segment (from wherever the last one ended) when done.
    #[serde(default)]
    pub repeat: bool,
    /// Hold still at the start point this long before the first segment, once (not repeated):
    /// the user holds the grip at home while the rig homes.
    #[serde(default)]
    pub start_hold_s: f64,
}

impl Script {
    /// Hold at one point forever.
    pub fn hold(at_m: DVec3) -> Script {
        Script {
            segments: vec![Segment::Hold { at_m: at_m.to_array(), for_s: 1.0 }],
            repeat: true,
            start_hold_s: 0.0,
        }
    }

    pub fn from_segments(segments: Vec<Segment>, repeat: bool) -> Script {
        Script { segments, repeat, start_hold_s: 0.0 }
    }

    /// The same script, held still at its start for `s` seconds first.
    pub fn with_start_hold(mut self, s: f64) -> Script {
        self.start_hold_s = s;
        self
    }

    /// Loads every `Trajectory { file }` (relative paths against `base_dir`) and validates every
    /// segment. `what` names the script in messages (e.g. "scripts.ron hand 0").
    pub fn prepare(&mut self, base_dir: &Path, what: &str) -> Result<(), SimRigError> {
        for seg in &mut self.segments {
            if let Segment::Trajectory { file } = seg {
                let p = PathBuf::from(&*file);
                let path = if p.is_absolute() { p } else { base_dir.join(p) };
                *seg = Segment::recorded_from_file(&path)?;
            }
        }
        self.validate(what)
    }

    /// Validates a prepared script (no `Trajectory` left to load).
    pub fn validate(&self, what: &str) -> Result<(), SimRigError> {
        if !(self.start_hold_s.is_finite() && self.start_hold_s >= 0.0) {
            return Err(SimRigError::InvalidScript {
                script: what.to_owned(),
                segment: 0,
                problem: format!("start_hold_s must be a finite time >= 0, not {}", self.start_hold_s),
            });
        }
        for (i, seg) in self.segments.iter().enumerate() {
            seg.validate(what, i)?;
        }
        if self.repeat && !self.segments.is_empty() {
            // A circle's length depends on where it starts; from its own centre it is the
            // shortest, so this check is conservative only for degenerate scripts.
            let total: f64 = self
                .segments
                .iter()
                .map(|s| match s {
                    Segment::Circle { turns, period_s, .. } => turns * period_s,
                    other => other.duration_s(DVec3::ZERO).unwrap_or(0.0),
                })
                .sum();
            if total <= 0.0 {
                return Err(SimRigError::InvalidScript {
                    script: what.to_owned(),
                    segment: 0,
                    problem: "a repeating script must last longer than 0 s in total".to_owned(),
                });
            }
        }
        Ok(())
    }

    /// Total length of one pass from `start_m`; `None` if it repeats (forever) or has an
    /// unprepared trajectory.
    pub fn duration_s(&self, start_m: DVec3) -> Option<f64> {
        if self.repeat {
            return None;
        }
        let mut cursor = ScriptCursor::new(start_m);
        let mut total = self.start_hold_s;
        let mut from = start_m;
        for (i, seg) in self.segments.iter().enumerate() {
            let d = seg.duration_s(from)?;
            total += d;
            from = cursor.segment_end(self, i, from, d);
        }
        Some(total)
    }

    /// Target at `t_s` for a hand starting at `start_m`. Replays from the start each call (cheap
    /// except for long sparring); use a [`ScriptCursor`] to follow time.
    pub fn target_at(&self, start_m: DVec3, t_s: f64) -> Target {
        ScriptCursor::new(start_m).target(self, t_s)
    }
}

/// Two-hand script file: `(kind: "script", version: 1, hands: ((segments: [...], repeat: true), (...)))`
/// (a commented example: configs/script-example.ron).
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScriptFile {
    pub version: u32,
    pub hands: [Script; 2],
}

impl ScriptFile {
    pub const VERSION: u32 = 1;

    /// Reads, parses and prepares a script file (trajectories relative to its folder).
    pub fn load(path: &Path) -> Result<ScriptFile, SimRigError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimRigError::Io {
            file: path.display().to_string(),
            what: "the script file",
            source,
        })?;
        ScriptFile::from_str(&text, &path.display().to_string())
    }

    /// Parses and prepares script text. `origin_name` names it in messages; if it is a path,
    /// relative trajectory files are looked up in its folder.
    #[allow(clippy::should_implement_trait)] // needs the origin name, so not `FromStr`
    pub fn from_str(text: &str, origin_name: &str) -> Result<ScriptFile, SimRigError> {
        let text =
            &spidar_config::expect_kind(text, origin_name, spidar_config::FileKind::Script).map_err(|e| {
                SimRigError::Parse { file: e.origin, line: e.line, column: e.column, message: e.message }
            })?;
        let mut file: ScriptFile = ron::from_str(text).map_err(|e| {
            let mut message = e.code.to_string();
            if matches!(e.code, ron::Error::ExpectedStructLike) {
                // The most common slip: `[x, y, z]` for a point, which RON reads as a list.
                message
                    .push_str(" (tuples are written in parentheses: points as (x, y, z), hands as (.., ..))");
            }
            SimRigError::Parse {
                file: origin_name.to_owned(),
                line: e.span.start.line,
                column: e.span.start.col,
                message,
            }
        })?;
        if file.version != Self::VERSION {
            return Err(SimRigError::Parse {
                file: origin_name.to_owned(),
                line: 1,
                column: 1,
                message: format!(
                    "version: {} is not supported; this build reads version {}",
                    file.version,
                    Self::VERSION
                ),
            });
        }
        let base = Path::new(origin_name).parent().unwrap_or(Path::new("")).to_path_buf();
        for (i, hand) in file.hands.iter_mut().enumerate() {
            hand.prepare(&base, &format!("{origin_name} hand {i}"))?;
        }
        Ok(file)
    }
}

/// Names accepted by [`builtin_script`].
pub const BUILTIN_SCRIPTS: &[&str] = &["hold", "circle", "spar", "tour"];

/// Targets of the "tour" script for the rig-check scene (configs/scene-walls.ron): a front wall at
/// rig z = -0.30 m, a table at rig y = -0.20 m (pressed 20 cm in front of the body: straight below
/// the origin this frame's strings need 15-20 N just to hold zero force) and a ball of radius 0.08 m centred at rig
/// (0, 0.25, -0.12) m (world = rig + (0, 1.10, 0)). With a 4 cm fist each target is 1.5 cm past
/// first contact, so the 200 N/m arm presses with about 3 N: inside the default 4 N limit.
pub mod tour {
    /// The tour pushes the grip centre to z = FRONT_TARGET_Z_M.
    pub const FRONT_TARGET_Z_M: f64 = -0.275;
    /// The tour pushes the grip centre down to y = FLOOR_TARGET_Y_M at z = FLOOR_TARGET_Z_M.
    pub const FLOOR_TARGET_Y_M: f64 = -0.175;
    pub const FLOOR_TARGET_Z_M: f64 = -0.20;
    /// Both hands squeeze the ball from the sides, to x = -/+ BALL_PRESS_X_M at the centre's height.
    pub const BALL_CENTRE_M: [f64; 3] = [0.0, 0.25, -0.12];
    pub const BALL_PRESS_X_M: f64 = 0.105;
    pub const REACH_S: f64 = 1.0;
    pub const PRESS_S: f64 = 1.5;
    pub const REST_S: f64 = 0.5;
}

/// Built-in scripts for both hands around their home positions; `None` for an unknown name
/// (see [`BUILTIN_SCRIPTS`]).
pub fn builtin_script(name: &str, home_m: [DVec3; 2], seed: u64) -> Option<[Script; 2]> {
    let per_hand = |hand: usize| -> Script {
        let home = home_m[hand];
        match name {
            "circle" => Script::from_segments(
                vec![Segment::Circle {
                    centre_m: home.to_array(),
                    radius_m: 0.1,
                    normal: [0.0, 0.0, 1.0],
                    period_s: 2.0,
                    turns: 1.0,
                }],
                true,
            ),
            "spar" => Script::from_segments(
                vec![Segment::Spar {
                    // Different, but seed-determined, streams for the two hands.
                    seed: seed ^ 0x9E37_79B9_7F4A_7C15u64.wrapping_mul(hand as u64 + 1),
                    centre_m: home.to_array(),
                    half_extent_m: [0.2, 0.2, 0.25],
                    for_s: 600.0,
                }],
                true,
            ),
            "tour" => {
                use tour::*;
                let reach = |to: DVec3| Segment::Reach { to_m: to.to_array(), duration_s: REACH_S };
                let hold = |at: DVec3, for_s: f64| Segment::Hold { at_m: at.to_array(), for_s };
                let front = DVec3::new(home.x, home.y, FRONT_TARGET_Z_M);
                let floor = DVec3::new(home.x, FLOOR_TARGET_Y_M, FLOOR_TARGET_Z_M);
                let mut segs = vec![
                    hold(home, REST_S),
                    reach(front),
                    hold(front, PRESS_S),
                    reach(home),
                    hold(home, REST_S),
                    reach(floor),
                    hold(floor, PRESS_S),
                    reach(home),
                    hold(home, REST_S),
                ];
                let side = if hand == 0 { -1.0 } else { 1.0 };
                let ball = DVec3::from(BALL_CENTRE_M) + DVec3::X * (side * BALL_PRESS_X_M);
                segs.extend([reach(ball), hold(ball, PRESS_S), reach(home)]);
                Script::from_segments(segs, true)
            }
            _ => Script::hold(home),
        }
    };
    if !BUILTIN_SCRIPTS.contains(&name) {
        return None;
    }
    Some([per_hand(0), per_hand(1)])
}

/// Minimum-jerk position fraction and its derivative (per unit tau) at tau in [0, 1].
fn min_jerk(tau: f64) -> (f64, f64) {
    let t = tau.clamp(0.0, 1.0);
    let t2 = t * t;
    let t3 = t2 * t;
    (t3 * (10.0 - 15.0 * t + 6.0 * t2), 30.0 * t2 * (1.0 - 2.0 * t + t2))
}

fn min_jerk_move(from: DVec3, to: DVec3, duration_s: f64, t: f64) -> Target {
    if duration_s <= 0.0 {
        return Target { pos_m: to, vel_m_per_s: DVec3::ZERO };
    }
    let (s, ds) = min_jerk(t / duration_s);
    Target { pos_m: from + (to - from) * s, vel_m_per_s: (to - from) * (ds / duration_s) }
}

/// A circle segment resolved against its start point.
struct CircleGeom {
    centre: DVec3,
    radius: f64,
    e1: DVec3,
    e2: DVec3,
    period_s: f64,
    turns: f64,
    approach_s: f64,
    from: DVec3,
}

impl CircleGeom {
    fn new(seg: &Segment, from: DVec3) -> CircleGeom {
        let Segment::Circle { centre_m, radius_m, normal, period_s, turns } = seg else {
            // Only called for circles; a harmless degenerate circle otherwise.
            return CircleGeom {
                centre: from,
                radius: 0.0,
                e1: DVec3::X,
                e2: DVec3::Y,
                period_s: 1.0,
                turns: 0.0,
                approach_s: 0.0,
                from,
            };
        };
        let centre = DVec3::from(*centre_m);
        let n = DVec3::from(*normal).try_normalize().unwrap_or(DVec3::Z);
        let in_plane = |v: DVec3| (v - n * v.dot(n)).try_normalize();
        let e1 = in_plane(from - centre)
            .or_else(|| in_plane(DVec3::X))
            .or_else(|| in_plane(DVec3::Y))
            .unwrap_or(DVec3::X);
        let e2 = n.cross(e1);
        let start = centre + e1 * *radius_m;
        let approach_s = if (start - from).length() > 1e-3 { period_s / 4.0 } else { 0.0 };
        CircleGeom { centre, radius: *radius_m, e1, e2, period_s: *period_s, turns: *turns, approach_s, from }
    }

    fn point(&self, angle: f64) -> DVec3 {
        self.centre + (self.e1 * angle.cos() + self.e2 * angle.sin()) * self.radius
    }

    fn eval(&self, t: f64) -> Target {
        if t < self.approach_s {
            return min_jerk_move(self.from, self.point(0.0), self.approach_s, t);
        }
        let total = self.turns * self.period_s;
        let tc = (t - self.approach_s).min(total);
        let omega = TAU / self.period_s;
        let angle = omega * tc;
        let vel = if tc < total {
            (self.e2 * angle.cos() - self.e1 * angle.sin()) * (self.radius * omega)
        } else {
            DVec3::ZERO
        };
        Target { pos_m: self.point(angle), vel_m_per_s: vel }
    }
}

/// One move of a sparring stream.
#[derive(Clone, Copy, Debug)]
enum Move {
    Hold { at: DVec3, dur: f64 },
    Reach { from: DVec3, to: DVec3, dur: f64 },
    Jab { from: DVec3, to: DVec3, out: f64, back: f64 },
}

impl Move {
    fn duration(&self) -> f64 {
        match *self {
            Move::Hold { dur, .. } | Move::Reach { dur, .. } => dur,
            Move::Jab { out, back, .. } => out + back,
        }
    }

    fn end(&self) -> DVec3 {
        match *self {
            Move::Hold { at, .. } => at,
            Move::Reach { to, .. } => to,
            Move::Jab { from, .. } => from,
        }
    }

    fn eval(&self, t: f64) -> Target {
        match *self {
            Move::Hold { at, .. } => Target { pos_m: at, vel_m_per_s: DVec3::ZERO },
            Move::Reach { from, to, dur } => min_jerk_move(from, to, dur, t),
            Move::Jab { from, to, out, back } => {
                if t < out {
                    min_jerk_move(from, to, out, t)
                } else {
                    min_jerk_move(to, from, back, t - out)
                }
            }
        }
    }
}

/// The lazily generated move stream of one `Spar` segment.
#[derive(Clone, Debug)]
struct SparState {
    rng: Pcg64Mcg,
    centre: DVec3,
    half: DVec3,
    /// Segment-relative time at which `current` started.
    move_start: f64,
    current: Move,
}

impl SparState {
    fn new(seed: u64, centre: DVec3, half: DVec3, from: DVec3) -> SparState {
        let mut s = SparState {
            rng: Pcg64Mcg::seed_from_u64(seed),
            centre,
            half,
            move_start: 0.0,
            current: Move::Hold { at: from, dur: 0.0 },
        };
        // First a guard shift into the box, so that everything after stays inside it.
        let to = s.point_in_box(DVec3::splat(-0.7), DVec3::splat(0.7));
        let dur = s.rng.random_range(0.4..0.9);
        s.current = Move::Reach { from, to, dur };
        s
    }

    /// A uniformly random point of the box, in box-relative coordinates within [lo, hi] per axis.
    fn point_in_box(&mut self, lo: DVec3, hi: DVec3) -> DVec3 {
        let mut u = DVec3::ZERO;
        for k in 0..3 {
            u[k] = lo[k] + (hi[k] - lo[k]) * self.rng.random::<f64>();
        }
        self.centre + self.half * u
    }

    fn next_move(&mut self, from: DVec3) -> Move {
        let r: f64 = self.rng.random();
        if r < 0.4 {
            // Jab: forward (-z), roughly at chest to head height, then back to the guard.
            let to = self.point_in_box(DVec3::new(-0.6, -0.3, -1.0), DVec3::new(0.6, 0.8, -0.6));
            let out = self.rng.random_range(0.15..0.35);
            let back = self.rng.random_range(0.25..0.45);
            Move::Jab { from, to, out, back }
        } else if r < 0.75 {
            let to = self.point_in_box(DVec3::splat(-0.7), DVec3::splat(0.7));
            let dur = self.rng.random_range(0.4..0.9);
            Move::Reach { from, to, dur }
        } else {
            Move::Hold { at: from, dur: self.rng.random_range(0.1..0.5) }
        }
    }

    /// Segment-relative time `t`, which must not go backwards between calls.
    fn eval(&mut self, t: f64) -> Target {
        // Every move lasts >= 0.1 s, so this loop ends.
        while t >= self.move_start + self.current.duration() {
            self.move_start += self.current.duration();
            let from = self.current.end();
            self.current = self.next_move(from);
        }
        self.current.eval(t - self.move_start)
    }
}

/// Follows a [`Script`] through time without allocating.
#[derive(Clone, Debug)]
pub struct ScriptCursor {
    start_m: DVec3,
    /// Segment playing, segment start time (script time) and where the target was then.
    seg: usize,
    seg_t0: f64,
    seg_from: DVec3,
    /// Move stream of the current segment if it is a `Spar`.
    spar: Option<SparState>,
    /// Set when a non-repeating script has ended: the target stays here.
    finished: Option<DVec3>,
    last_t: f64,
}

impl ScriptCursor {
    pub fn new(start_m: DVec3) -> ScriptCursor {
        ScriptCursor {
            start_m,
            seg: 0,
            seg_t0: 0.0,
            seg_from: start_m,
            spar: None,
            finished: None,
            last_t: 0.0,
        }
    }

    /// Back to the script's start (from `start_m`).
    pub fn reset(&mut self, start_m: DVec3) {
        *self = ScriptCursor::new(start_m);
    }

    /// Target at script time `t_s` (time since the script started). Never allocates or panics;
    /// going back in time replays from the start.
    pub fn target(&mut self, script: &Script, t_s: f64) -> Target {
        if t_s < script.start_hold_s {
            return Target { pos_m: self.start_m, vel_m_per_s: DVec3::ZERO };
        }
        let t_s = t_s - script.start_hold_s;
        let t = if t_s.is_finite() { t_s } else { self.last_t };
        if t < self.last_t {
            self.reset(self.start_m);
        }
        self.last_t = t;
        let n = script.segments.len();
        if n == 0 {
            return Target { pos_m: self.start_m, vel_m_per_s: DVec3::ZERO };
        }
        // Segments lasting no time are skipped; stop if a whole pass is such segments.
        let mut skipped_empty = 0;
        loop {
            if let Some(at) = self.finished {
                return Target { pos_m: at, vel_m_per_s: DVec3::ZERO };
            }
            let Some(seg) = script.segments.get(self.seg) else {
                self.finished = Some(self.seg_from);
                continue;
            };
            // An unprepared trajectory has no data: treat it as a zero-length hold.
            let d = seg.duration_s(self.seg_from).unwrap_or(0.0);
            if t < self.seg_t0 + d {
                break;
            }
            let end = self.segment_end(script, self.seg, self.seg_from, d);
            skipped_empty = if d > 0.0 { 0 } else { skipped_empty + 1 };
            self.seg_t0 += d;
            self.seg_from = end;
            self.spar = None;
            self.seg += 1;
            if self.seg >= n {
                if script.repeat && skipped_empty < n {
                    self.seg = 0;
                } else {
                    self.finished = Some(end);
                }
            }
        }
        let seg_t = t - self.seg_t0;
        self.eval_segment(script, self.seg, self.seg_from, seg_t)
    }

    /// Where segment `i` (started at `from`, lasting `d`) ends; leaves the spar state at its end.
    fn segment_end(&mut self, script: &Script, i: usize, from: DVec3, d: f64) -> DVec3 {
        match script.segments.get(i) {
            Some(Segment::Hold { at_m, .. }) => DVec3::from(*at_m),
            Some(Segment::Reach { to_m, .. }) => DVec3::from(*to_m),
            Some(Segment::Jab { .. }) | None | Some(Segment::Trajectory { .. }) => from,
            Some(seg @ Segment::Circle { .. }) => CircleGeom::new(seg, from).eval(d).pos_m,
            Some(Segment::Spar { .. }) => self.eval_segment(script, i, from, d).pos_m,
            Some(Segment::Recorded(r)) => r.samples.last().map_or(from, |s| s.pos_m),
        }
    }

    fn eval_segment(&mut self, script: &Script, i: usize, from: DVec3, t: f64) -> Target {
        let hold = |at: DVec3| Target { pos_m: at, vel_m_per_s: DVec3::ZERO };
        match script.segments.get(i) {
            None | Some(Segment::Trajectory { .. }) => hold(from),
            Some(Segment::Hold { at_m, .. }) => hold(DVec3::from(*at_m)),
            Some(Segment::Reach { to_m, duration_s }) => {
                min_jerk_move(from, DVec3::from(*to_m), *duration_s, t)
            }
            Some(Segment::Jab { to_m, out_s, back_s }) => {
                let to = DVec3::from(*to_m);
                if t < *out_s {
                    min_jerk_move(from, to, *out_s, t)
                } else {
                    min_jerk_move(to, from, *back_s, t - out_s)
                }
            }
            Some(seg @ Segment::Circle { .. }) => CircleGeom::new(seg, from).eval(t),
            Some(Segment::Spar { seed, centre_m, half_extent_m, .. }) => {
                let spar = self.spar.get_or_insert_with(|| {
                    SparState::new(*seed, DVec3::from(*centre_m), DVec3::from(*half_extent_m), from)
                });
                spar.eval(t)
            }
            Some(Segment::Recorded(r)) => r.eval(t),
        }
    }
}

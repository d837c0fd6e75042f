//! Guided recording: ask the operator for each pose, wait until the grip is still, average the
//! counts, check the pose, and keep it in a session.
//!
//! Why it exists: the fit is only as good as its data. A pose taken while the grip still moves, on
//! a slack string, or on top of an earlier pose makes a fit worse or degenerate, so each pose is
//! checked here, while the operator can still redo it.
//!
//! What it must never do: render force. While recording, every string is held at the rig's
//! minimum tension (`tension_min_n`, volts from the configured `volts_per_newton`), which keeps
//! the strings taut and pulls the grip with at most a few newtons; the device is deactivated
//! (zero output) when recording ends or fails. It works against any [`Device`]; on the simulated
//! rig the [`SimOperator`] moves a scripted hand where a person would move the grip.

use glam::DVec3;
use spidar_device::sim::{Script, Segment, SimRig};
use spidar_device::{Device, Input, Output};
use spidar_rt::Rig;

use crate::jig::JigFile;
use crate::model::HandGeometry;
use crate::session::{PoseKind, PoseRecord, SessionFile, SESSION_FILE_VERSION};
use crate::CalibError;

/// What the operator is asked to do.
#[derive(Clone, Debug, PartialEq)]
pub enum Request {
    /// Hold the grip at the home point.
    Home { at_m: DVec3 },
    /// Put the grip on a jig point.
    Jig { label: String, at_m: DVec3 },
    /// Put the grip anywhere new; `suggest_m` spreads poses through the workspace.
    Free { index: usize, of: usize, suggest_m: DVec3 },
}

impl std::fmt::Display for Request {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = |v: DVec3| format!("({:+.3}, {:+.3}, {:+.3}) m", v.x, v.y, v.z);
        match self {
            Request::Home { at_m } => write!(f, "hold the grip at the home point {}", p(*at_m)),
            Request::Jig { label, at_m } => write!(f, "put the grip on jig point {label} at {}", p(*at_m)),
            Request::Free { index, of, suggest_m } => {
                write!(
                    f,
                    "free pose {}/{of}: move the grip somewhere new, e.g. near {}",
                    index + 1,
                    p(*suggest_m)
                )
            }
        }
    }
}

/// The operator's answer to a [`Request`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Answer {
    /// The grip is there; the recorder checks stillness and records.
    Ready,
    /// Leave this pose out (only free poses may be skipped; the next suggestion follows).
    Skip,
}

/// The person (or script) that moves the grip.
pub trait Operator<D: Device> {
    /// Ask for `req` on `hand`'s grip. Returns once the operator says the grip is there (a real
    /// operator: presses Enter) or that this free pose is skipped; stillness is then checked by
    /// the recorder. An operator who waits keeps `dev` exchanging (strings held at minimum
    /// tension, the tick's counts read); aborting returns [`CalibError::Aborted`].
    fn request(&mut self, dev: &mut D, hand: usize, req: &Request) -> Result<Answer, CalibError>;
    /// Progress lines and warnings for the operator.
    fn tell(&mut self, line: &str);
}

/// Moves the simulated user's hand to each requested point (minimum-jerk reach, then hold).
pub struct SimOperator {
    /// Print what a person would be told (to stderr).
    pub verbose: bool,
    /// Everything told, for tests and reports.
    pub log: Vec<String>,
}

impl SimOperator {
    pub fn new(verbose: bool) -> SimOperator {
        SimOperator { verbose, log: Vec::new() }
    }
}

impl Operator<SimRig> for SimOperator {
    fn request(&mut self, dev: &mut SimRig, hand: usize, req: &Request) -> Result<Answer, CalibError> {
        let to = match req {
            Request::Home { at_m } | Request::Jig { at_m, .. } => *at_m,
            Request::Free { suggest_m, .. } => *suggest_m,
        };
        let from = dev.truth().hands[hand].pos_m;
        let duration_s = (0.3 + 2.0 * from.distance(to)).min(2.0);
        let script = Script::from_segments(
            vec![
                Segment::Reach { to_m: to.to_array(), duration_s },
                Segment::Hold { at_m: to.to_array(), for_s: 1e6 },
            ],
            false,
        );
        dev.try_set_script(hand, script)?;
        Ok(Answer::Ready)
    }

    fn tell(&mut self, line: &str) {
        if self.verbose {
            eprintln!("{line}");
        }
        self.log.push(line.to_string());
    }
}

/// Recording thresholds.
#[derive(Clone, Debug)]
pub struct RecordOptions {
    /// The grip counts as still when no string moved more than `still_range_m` over this long.
    pub still_window_s: f64,
    pub still_range_m: f64,
    /// Counts are averaged over this long once still (and it must stay still throughout).
    pub average_s: f64,
    /// Give up on a pose when the grip is not still this long after the request.
    pub timeout_s: f64,
    /// A pose whose string lengths differ from an earlier pose's by less than this (RMS over the
    /// four strings) adds no information and is refused.
    pub min_separation_m: f64,
    /// A pose whose lengths are inconsistent by more than this with the current geometry (RMS
    /// residual of the position solve) draws a slack warning.
    pub slack_residual_m: f64,
    /// Sleep one tick period between exchanges (a real device paced by the wall clock). The
    /// simulated rig's time is its exchange count, so it runs unpaced.
    pub pace: bool,
    /// Non-zero once a stop was asked for (a stop signal): the recording ends at the next
    /// exchange with [`CalibError::Aborted`], and its caller switches the outputs off.
    pub stop: Option<std::sync::Arc<std::sync::atomic::AtomicU32>>,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            still_window_s: 0.3,
            still_range_m: 0.5e-3,
            average_s: 0.5,
            timeout_s: 30.0,
            min_separation_m: 0.02,
            slack_residual_m: 0.05,
            pace: false,
            stop: None,
        }
    }
}

/// What to record: per hand the home point, then jig points, then `free` free poses.
#[derive(Clone, Debug)]
pub struct Plan {
    pub hands: Vec<usize>,
    pub jig: Option<JigFile>,
    pub free_per_hand: usize,
    /// Half extents of the box around each hand's home that free-pose suggestions fill.
    pub free_half_extent_m: DVec3,
}

impl Plan {
    /// Suggested free-pose points for `hand`: a Halton sequence through the box around home, so
    /// any prefix of it is spread evenly (a person may stop early).
    pub fn free_suggestions(&self, rig: &Rig, hand: usize) -> Vec<DVec3> {
        let home = rig.hands[hand].home_m;
        (0..self.free_per_hand)
            .map(|k| {
                let u = DVec3::new(halton(k + 1, 2), halton(k + 1, 3), halton(k + 1, 5)) * 2.0 - DVec3::ONE;
                home + u * self.free_half_extent_m
            })
            .collect()
    }
}

fn halton(mut i: usize, base: usize) -> f64 {
    let (mut f, mut r) = (1.0, 0.0);
    while i > 0 {
        f /= base as f64;
        r += f * (i % base) as f64;
        i /= base;
    }
    r
}

/// Drives a device for recording: strings at minimum tension, counts read once per tick.
pub struct Recorder<'r, D: Device> {
    dev: D,
    rig: &'r Rig,
    opts: RecordOptions,
    out: Output,
    inp: Input,
    /// Geometry used for the checks: configured anchors, lengths at zero from the home pose.
    check_geometry: [Option<HandGeometry>; 2],
    warnings: Vec<String>,
}

/// The output that holds every string of the rig at its minimum tension: what the device gets
/// all through recording, also while the operator moves the grip.
pub fn holding_output(rig: &Rig) -> Output {
    let mut out = Output::default();
    for hr in &rig.hands {
        for i in 0..4 {
            out.volts[hr.channels[i]] = hr.tension_min_n * hr.volts_per_newton[i];
        }
    }
    out
}

impl<'r, D: Device> Recorder<'r, D> {
    /// Opens and activates the device with every string of the rig at minimum tension.
    pub fn new(mut dev: D, rig: &'r Rig, opts: RecordOptions) -> Result<Recorder<'r, D>, CalibError> {
        dev.open()?;
        Recorder::opened(dev, rig, opts)
    }

    /// As [`Recorder::new`] for a device already opened (a board opened with detailed errors):
    /// opening again would enumerate the boards twice.
    pub fn opened(mut dev: D, rig: &'r Rig, opts: RecordOptions) -> Result<Recorder<'r, D>, CalibError> {
        let out = holding_output(rig);
        dev.activate()?;
        let check_geometry = [0, 1].map(|h| HandGeometry::from_rig(&rig.hands[h]));
        Ok(Recorder { dev, rig, opts, out, inp: Input::default(), check_geometry, warnings: Vec::new() })
    }

    pub fn device(&mut self) -> &mut D {
        &mut self.dev
    }

    /// Warnings given so far (also told to the operator).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Switches the outputs off and hands the device back.
    pub fn finish(mut self) -> Result<D, CalibError> {
        self.dev.deactivate()?;
        Ok(self.dev)
    }

    fn ticks(&self, s: f64) -> usize {
        (s / self.rig.period_s).round().max(1.0) as usize
    }

    /// One exchange; transient device errors are retried for up to 50 ticks.
    fn exchange(&mut self) -> Result<[i64; 16], CalibError> {
        let mut failures = 0;
        loop {
            if self.opts.stop.as_ref().is_some_and(|s| s.load(std::sync::atomic::Ordering::SeqCst) > 0) {
                return Err(CalibError::Aborted("a stop signal (SIGINT, SIGTERM or SIGHUP)".into()));
            }
            if self.opts.pace {
                std::thread::sleep(std::time::Duration::from_secs_f64(self.rig.period_s));
            }
            match self.dev.exchange(&self.out, &mut self.inp) {
                Ok(()) => return Ok(self.inp.counts),
                Err(e) if failures < 50 && e.kind() != spidar_device::ErrorKind::Disconnected => {
                    failures += 1
                }
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Waits until the hand's grip is still, then averages its counts; returns (mean, std, n).
    fn still_average(&mut self, hand: usize) -> Result<([f64; 4], [f64; 4], u32), CalibError> {
        let ch = self.rig.hands[hand].channels;
        let mpc = self.rig.hands[hand].metres_per_count;
        let window = self.ticks(self.opts.still_window_s);
        let avg = self.ticks(self.opts.average_s);
        let timeout = self.ticks(self.opts.timeout_s);
        let range_counts: [f64; 4] = std::array::from_fn(|i| self.opts.still_range_m / mpc[i].abs());
        let mut recent: std::collections::VecDeque<[i64; 4]> =
            std::collections::VecDeque::with_capacity(window + avg);
        for _ in 0..timeout {
            let c = self.exchange()?;
            recent.push_back(ch.map(|k| c[k]));
            if recent.len() > window + avg {
                recent.pop_front();
            }
            // Still over the whole buffer once it holds the window plus the average.
            if recent.len() == window + avg {
                let still = (0..4).all(|i| {
                    let (lo, hi) =
                        recent.iter().fold((i64::MAX, i64::MIN), |(lo, hi), s| (lo.min(s[i]), hi.max(s[i])));
                    ((hi - lo) as f64) <= range_counts[i]
                });
                if still {
                    let tail: Vec<[i64; 4]> = recent.iter().skip(window).copied().collect();
                    let n = tail.len() as f64;
                    let mean: [f64; 4] =
                        std::array::from_fn(|i| tail.iter().map(|s| s[i] as f64).sum::<f64>() / n);
                    let std: [f64; 4] = std::array::from_fn(|i| {
                        (tail.iter().map(|s| (s[i] as f64 - mean[i]).powi(2)).sum::<f64>()
                            / (n - 1.0).max(1.0))
                        .sqrt()
                    });
                    return Ok((mean, std, tail.len() as u32));
                }
            }
        }
        Err(CalibError::Recording(format!(
            "hand {hand}: the grip did not keep still (within {:.1} mm for {:.1} s) in {:.0} s: hold it steady, \
             or rest it on the jig",
            self.opts.still_range_m * 1e3,
            self.opts.still_window_s + self.opts.average_s,
            self.opts.timeout_s
        )))
    }

    fn warn(&mut self, op: &mut dyn FnMut(&str), line: String) {
        op(&format!("  warning: {line}"));
        self.warnings.push(line);
    }

    /// Records one pose. `Ok(None)`: refused (the reason was told); ask for another.
    pub fn record_pose<O: Operator<D>>(
        &mut self,
        op: &mut O,
        hand: usize,
        req: &Request,
        earlier: &[PoseRecord],
    ) -> Result<Option<PoseRecord>, CalibError> {
        if op.request(&mut self.dev, hand, req)? == Answer::Skip {
            op.tell("  skipped");
            return Ok(None);
        }
        let (counts, counts_std, samples) = self.still_average(hand)?;
        let hr = &self.rig.hands[hand];
        let kind = match req {
            Request::Home { at_m } => PoseKind::Home { at_m: at_m.to_array() },
            Request::Jig { label, at_m } => PoseKind::Jig { label: label.clone(), at_m: at_m.to_array() },
            Request::Free { .. } => PoseKind::Free,
        };
        if let Request::Home { at_m } = req {
            if self.check_geometry[hand].is_none() {
                self.check_geometry[hand] = Some(HandGeometry::homed(hr, &counts, *at_m));
            }
        }
        // No information: the same string lengths as an earlier pose of this hand.
        for (k, e) in earlier.iter().enumerate().filter(|(_, e)| e.hand == hand) {
            let d2: f64 = (0..4).map(|i| ((counts[i] - e.counts[i]) * hr.metres_per_count[i]).powi(2)).sum();
            let d = (d2 / 4.0).sqrt();
            if d < self.opts.min_separation_m {
                let mut tell = |s: &str| op.tell(s);
                self.warn(
                    &mut tell,
                    format!(
                        "hand {hand}: this pose repeats pose {k} (string lengths within {:.1} mm RMS): it adds no \
                         information and is not kept; move at least {:.0} mm away",
                        d * 1e3,
                        self.opts.min_separation_m * 1e3
                    ),
                );
                return Ok(None);
            }
        }
        // Slack: a string whose counts wobble while the others are steady, or lengths that do not
        // meet at a point.
        let mpc = hr.metres_per_count;
        let spread_m: [f64; 4] = std::array::from_fn(|i| counts_std[i] * mpc[i].abs());
        let median_spread = {
            let mut s = spread_m;
            s.sort_by(f64::total_cmp);
            0.5 * (s[1] + s[2])
        };
        for (i, &spread) in spread_m.iter().enumerate() {
            if spread > 0.1e-3 && spread > 5.0 * median_spread {
                let line = format!(
                    "hand {hand} string {i}: its length wobbles by {:.2} mm while the others hold still: slack? \
                     check its tension",
                    spread * 1e3
                );
                let mut tell = |s: &str| op.tell(s);
                self.warn(&mut tell, line);
            }
        }
        if let Some(g) = self.check_geometry[hand] {
            let lengths = g.lengths(&counts);
            if let Some(i) = (0..4).find(|&i| lengths[i] < 0.05) {
                let line = format!(
                    "hand {hand} string {i}: reads {:.0} mm long, shorter than possible: the string is slack, \
                     off its pulley, or the counter jumped; pose not kept",
                    lengths[i] * 1e3
                );
                let mut tell = |s: &str| op.tell(s);
                self.warn(&mut tell, line);
                return Ok(None);
            }
            match g.position(&counts) {
                Some((_, residual)) if residual > self.opts.slack_residual_m => {
                    let line = format!(
                        "hand {hand}: the four lengths miss a common point by {:.0} mm RMS: a slack string, or \
                         configured anchors far off; the pose is kept, the fit will tell which",
                        residual * 1e3
                    );
                    let mut tell = |s: &str| op.tell(s);
                    self.warn(&mut tell, line);
                }
                _ => {}
            }
        }
        let worst_um = (0..4).map(|i| spread_m[i]).fold(0.0, f64::max) * 1e6;
        op.tell(&format!("  recorded: {samples} samples, worst string spread {worst_um:.0} um"));
        Ok(Some(PoseRecord { hand, kind, counts, counts_std, samples }))
    }

    /// Records a whole plan, telling progress; free poses that are refused are replaced by the
    /// next suggestion (at most twice as many attempts as poses asked for).
    pub fn record_plan<O: Operator<D>>(
        &mut self,
        op: &mut O,
        plan: &Plan,
        device_name: &str,
    ) -> Result<SessionFile, CalibError> {
        let mut poses: Vec<PoseRecord> = Vec::new();
        for &hand in &plan.hands {
            let hr = &self.rig.hands[hand];
            let jig: Vec<_> = plan
                .jig
                .iter()
                .flat_map(|j| j.fit_points.iter())
                .filter(|p| p.hand == hand)
                .cloned()
                .collect();
            let total = 1 + jig.len() + plan.free_per_hand;
            op.tell(&format!(
                "hand {hand} ({}): {total} poses: home, {} jig points, {} free poses",
                hr.label,
                jig.len(),
                plan.free_per_hand
            ));
            let mut done = 0;
            let home = Request::Home { at_m: hr.home_m };
            op.tell(&format!("[{}/{total}] {home}", done + 1));
            match self.record_pose(op, hand, &home, &poses)? {
                Some(p) => poses.push(p),
                None => {
                    return Err(CalibError::Recording(format!(
                        "hand {hand}: the home pose was refused (see warnings)"
                    )))
                }
            }
            done += 1;
            for jp in &jig {
                let req = Request::Jig { label: jp.label.clone(), at_m: jp.at() };
                op.tell(&format!("[{}/{total}] {req}", done + 1));
                if let Some(p) = self.record_pose(op, hand, &req, &poses)? {
                    poses.push(p);
                    done += 1;
                }
            }
            // Twice as many suggestions as poses, so refused ones are replaced.
            let extended = Plan { free_per_hand: plan.free_per_hand * 2, ..plan.clone() };
            let suggestions = extended.free_suggestions(self.rig, hand);
            let mut kept = 0;
            for s in suggestions {
                if kept == plan.free_per_hand {
                    break;
                }
                let req = Request::Free { index: kept, of: plan.free_per_hand, suggest_m: s };
                op.tell(&format!("[{}/{total}] {req}", done + 1));
                if let Some(p) = self.record_pose(op, hand, &req, &poses)? {
                    poses.push(p);
                    kept += 1;
                    done += 1;
                }
            }
            if kept < plan.free_per_hand {
                let line = format!("hand {hand}: only {kept} of {} free poses were kept", plan.free_per_hand);
                let mut tell = |s: &str| op.tell(s);
                self.warn(&mut tell, line);
            }
            // Back home, so the grip is where the next hand's operator expects it.
            op.request(&mut self.dev, hand, &home)?;
        }
        Ok(SessionFile {
            version: SESSION_FILE_VERSION,
            rig_name: self.rig.name.clone(),
            device: device_name.to_string(),
            recorded_utc: crate::utc_now(),
            poses,
        })
    }

    /// Records the grip at `at_m` without the checks (homing, verification).
    pub fn record_at<O: Operator<D>>(
        &mut self,
        op: &mut O,
        hand: usize,
        req: &Request,
    ) -> Result<([f64; 4], [f64; 4]), CalibError> {
        if op.request(&mut self.dev, hand, req)? == Answer::Skip {
            return Err(CalibError::Recording(format!("hand {hand}: {req}: this point cannot be skipped")));
        }
        let (c, s, _) = self.still_average(hand)?;
        Ok((c, s))
    }
}

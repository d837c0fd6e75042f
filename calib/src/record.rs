//! Guided recording: ask the operator for each pose, wait until the grip is still, average the
//! counts, check the pose, and keep it in a session.
//!
//! Why it exists: the fit is only as good as its data. A pose taken while the grip still moves, on
//! a slack string, or on top of an earlier pose makes a fit worse or degenerate, so each pose is
//! checked here, while the operator can still redo it.
//!
//! Stillness is judged from averaged string lengths against the noise measured at rest: the
//! samples are averaged in blocks of `block_s`, and the grip is still when no string's block
//! averages spread by more than `still_range_m` plus what the noise alone gives them (six standard
//! deviations of a block average, the noise estimated from successive differences, which a slow
//! movement does not inflate). So 3 counts of encoder noise pass and a grip that moves does not.
//!
//! Sessions survive: every kept pose is handed to a `save` callback at once (the caller writes
//! the session file atomically), a resumed session continues where it stopped after checking at
//! the home point that the counters are still the ones it was recorded with, a pose whose grip
//! would not keep still is asked for again instead of ending the session, and a tick whose reply
//! the rt-loop did not take (late, corrupt, a count that jumped) is left out ([`crate::ticks`]).
//!
//! What it must never do: drive the device. The rt-loop does, calibrating
//! (`TickCore::calibrate`): every string at the rig's minimum tension with zero net force, the
//! same rules for replies as `spidar run`, and its switch-off (zero output) when recording ends
//! or fails. This only reads the loop's tick records; on the simulated rig the [`SimOperator`]
//! moves a scripted hand where a person would move the grip.

use std::collections::VecDeque;

use glam::DVec3;
use spidar_device::sim::{Script, Segment};
use spidar_rt::Rig;

use crate::jig::JigFile;
use crate::model::HandGeometry;
use crate::session::{PoseKind, PoseRecord, SessionFile, SessionPlan};
use crate::ticks::{LoopStats, SimulatedRig, StopCheck, TickSource, Ticks, VirtualLoop};
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
pub trait Operator<S: TickSource> {
    /// Ask for `req` on `hand`'s grip. Returns once the operator says the grip is there (a real
    /// operator: presses Enter) or that this free pose is skipped; stillness is then checked by
    /// the recorder. An operator who waits keeps reading `ticks` (the loop's records do not pile
    /// up, stop requests and a lost board are seen); aborting returns [`CalibError::Aborted`].
    fn request(&mut self, ticks: &mut Ticks<S>, hand: usize, req: &Request) -> Result<Answer, CalibError>;
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

impl<S: TickSource + SimulatedRig> Operator<S> for SimOperator {
    fn request(&mut self, ticks: &mut Ticks<S>, hand: usize, req: &Request) -> Result<Answer, CalibError> {
        let Some(dev) = ticks.source_mut().sim_rig() else {
            return Err(CalibError::Options(
                "the simulated user moves the grips of the simulated rig only (--device sim)".into(),
            ));
        };
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
    /// The grip counts as still when, over this long plus `average_s`, no string's block averages
    /// spread by more than `still_range_m` beyond what the noise at rest explains.
    pub still_window_s: f64,
    pub still_range_m: f64,
    /// Samples are averaged over blocks this long before the stillness test.
    pub block_s: f64,
    /// Counts are averaged over at least this long once still (and it must stay still throughout)...
    pub average_s: f64,
    /// ... and longer, up to this, while the average is not yet known to `target_sem_m` (noisy
    /// encoders: 3 counts of noise average for 2 s).
    pub max_average_s: f64,
    /// Standard error of an averaged string length that ends the averaging early.
    pub target_sem_m: f64,
    /// A pose whose grip is not still this long after the request is not kept (and asked again).
    pub timeout_s: f64,
    /// Times a home or jig point is asked again after its grip would not keep still.
    pub attempts: usize,
    /// A pose whose string lengths differ from an earlier pose's by less than this (RMS over the
    /// four strings) adds no information and is refused.
    pub min_separation_m: f64,
    /// A pose whose lengths are inconsistent by more than this with the current geometry (RMS
    /// residual of the position solve) draws a slack warning.
    pub slack_residual_m: f64,
    /// The board counts as lost when no exchange succeeded for this long (late or bad replies
    /// before that are left out and counted).
    pub lost_after_s: f64,
    /// Resuming a session: at the home point the lengths must read within this (RMS over the
    /// strings) of the session's home pose, or the counters are not the ones it was recorded with.
    pub resume_max_offset_m: f64,
}

impl Default for RecordOptions {
    fn default() -> Self {
        RecordOptions {
            still_window_s: 0.3,
            still_range_m: 0.5e-3,
            block_s: 0.05,
            average_s: 0.5,
            max_average_s: 2.0,
            target_sem_m: 1.5e-6,
            timeout_s: 30.0,
            attempts: 3,
            min_separation_m: 0.02,
            slack_residual_m: 0.05,
            lost_after_s: 2.0,
            resume_max_offset_m: 0.02,
        }
    }
}

impl RecordOptions {
    /// Refuses non-finite and out-of-range thresholds, naming the option and its range.
    pub fn check(&self) -> Result<(), CalibError> {
        let range = |name: &str, v: f64, lo: f64, hi: f64, unit: &str| {
            if v.is_finite() && (lo..=hi).contains(&v) {
                Ok(())
            } else {
                Err(CalibError::Options(format!("{name} must be {lo} .. {hi}{unit} (got {v})")))
            }
        };
        range("the stillness window", self.still_window_s, 0.05, 10.0, " s")?;
        range("the stillness range", self.still_range_m, 1e-5, 0.02, " m")?;
        range("the averaging time", self.average_s, 0.01, 10.0, " s")?;
        range("the longest averaging time", self.max_average_s, self.average_s, 60.0, " s")?;
        range("the averaging target", self.target_sem_m, 1e-9, 1e-3, " m")?;
        range("the stillness block", self.block_s, 0.001, self.still_window_s.min(self.average_s), " s")?;
        range("the pose timeout", self.timeout_s, self.still_window_s + self.max_average_s, 3600.0, " s")?;
        range("the minimum pose separation", self.min_separation_m, 0.0, 0.5, " m")?;
        range("the slack residual", self.slack_residual_m, 1e-4, 1.0, " m")?;
        range("the board-lost time", self.lost_after_s, 0.01, 600.0, " s")?;
        range("the resume offset", self.resume_max_offset_m, 1e-4, 0.5, " m")?;
        if !(1..=100).contains(&self.attempts) {
            return Err(CalibError::Options(format!("attempts must be 1 .. 100 (got {})", self.attempts)));
        }
        Ok(())
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
    /// Refuses what cannot give a fit: an unknown or repeated hand, more free poses than
    /// [`crate::session::MAX_FREE_PER_HAND`], a box out of 0.05 .. 1 m, 1 to 3 jig points for a hand (they leave a
    /// rotation unobservable), or fewer poses than the fit needs (with metres per count fitted:
    /// free poses only need 17 per hand; home and 8 jig points need none).
    pub fn check(&self) -> Result<(), CalibError> {
        self.session_plan(None).check().map_err(CalibError::Options)?;
        let h = self.free_half_extent_m;
        if !(h.is_finite() && h.x == h.y && h.y == h.z) {
            return Err(CalibError::Options("the free-pose box must be a cube".into()));
        }
        for &hand in &self.hands {
            let jig = self.jig.iter().flat_map(|j| j.fit_points.iter()).filter(|p| p.hand == hand).count();
            if (1..4).contains(&jig) {
                return Err(CalibError::Options(format!(
                    "the jig has {jig} fit point(s) for hand {hand}: use at least 4 (not in one plane), or none"
                )));
            }
            // Unknowns 20 + 3 per free pose (less the 7 of the frame without jig points), 4
            // equations per pose, 8 to spare (as the fit asks).
            let gauge = if jig == 0 { 7 } else { 0 };
            let need = (24 - gauge - 4 * jig as i64).max(0) as usize;
            if self.free_per_hand < need {
                return Err(CalibError::Options(format!(
                    "{} free poses per hand: with {jig} jig points the fit needs at least {need} (give --free {need} \
                     or more{})",
                    self.free_per_hand,
                    if jig == 0 { ", or a jig with --jig" } else { "" }
                )));
            }
        }
        Ok(())
    }

    /// The plan as a session stores it.
    pub fn session_plan(&self, jig_file: Option<String>) -> SessionPlan {
        SessionPlan {
            hands: self.hands.clone(),
            jig_file,
            free_per_hand: self.free_per_hand,
            free_half_extent_m: self.free_half_extent_m.x,
        }
    }

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

/// A still grip's averaged counts.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Still {
    pub counts: [f64; 4],
    /// Standard deviation of the samples (the noise at rest).
    pub counts_std: [f64; 4],
    pub samples: u32,
}

/// The noise of each string's counts (standard deviation per sample), from successive
/// differences: a slow movement barely changes them, so it is the noise at rest even while the
/// grip settles.
pub fn noise_counts(buf: &[[i64; 4]]) -> [f64; 4] {
    std::array::from_fn(|i| {
        let diff2: f64 = buf.windows(2).map(|w| ((w[1][i] - w[0][i]) as f64).powi(2)).sum();
        (diff2 / (2.0 * (buf.len().max(2) - 1) as f64)).sqrt()
    })
}

/// Whether the samples in `buf` (oldest first) show a still grip: for every string the block
/// averages (`block` samples each) spread by at most `range_counts` plus six standard deviations
/// of a block average, with the noise from [`noise_counts`].
pub fn is_still(buf: &[[i64; 4]], block: usize, range_counts: &[f64; 4]) -> bool {
    let block = block.max(1);
    let blocks = buf.len() / block;
    if blocks < 2 {
        return false;
    }
    let sigma = noise_counts(buf);
    (0..4).all(|i| {
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for b in buf.chunks_exact(block) {
            let m = b.iter().map(|s| s[i] as f64).sum::<f64>() / block as f64;
            lo = lo.min(m);
            hi = hi.max(m);
        }
        hi - lo <= range_counts[i] + 6.0 * sigma[i] / (block as f64).sqrt()
    })
}

/// Records from a calibrating rt-loop's ticks (strings at minimum tension, counts read once per
/// tick).
pub struct Recorder<'r, S: TickSource> {
    ticks: Ticks<S>,
    rig: &'r Rig,
    opts: RecordOptions,
    /// Geometry used for the checks: configured anchors, lengths at zero from the home pose.
    check_geometry: [Option<HandGeometry>; 2],
    warnings: Vec<String>,
}

impl<'r, D: spidar_device::Device> Recorder<'r, VirtualLoop<D>> {
    /// Records from `dev` through a calibrating loop on this thread and the virtual clock
    /// ([`VirtualLoop`]); `opened`: the device was opened already.
    pub fn on_virtual_loop(
        dev: D,
        rig: &'r Rig,
        opts: RecordOptions,
        opened: bool,
    ) -> Result<Recorder<'r, VirtualLoop<D>>, CalibError> {
        opts.check()?;
        Recorder::new(VirtualLoop::start(dev, rig, opened)?, rig, opts)
    }
}

impl<'r, S: TickSource> Recorder<'r, S> {
    /// Records from `source`, a calibrating loop already running (its strings at minimum
    /// tension).
    pub fn new(source: S, rig: &'r Rig, opts: RecordOptions) -> Result<Recorder<'r, S>, CalibError> {
        opts.check()?;
        let ticks = Ticks::new(source, rig, opts.lost_after_s);
        let check_geometry = [0, 1].map(|h| HandGeometry::from_rig(&rig.hands[h]));
        Ok(Recorder { ticks, rig, opts, check_geometry, warnings: Vec::new() })
    }

    /// Polls `stop` every tick: when it says so, the session ends with [`CalibError::Interrupted`].
    pub fn set_stop(&mut self, stop: StopCheck) {
        self.ticks.set_stop(stop);
    }

    pub fn ticks(&mut self) -> &mut Ticks<S> {
        &mut self.ticks
    }

    /// What the loop's records showed so far: ticks, replies left out, count jumps, faults.
    pub fn loop_stats(&self) -> LoopStats {
        self.ticks.stats()
    }

    /// Warnings given so far (also told to the operator).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// Ends the loop (its switch-off) and hands the source back.
    pub fn finish(self) -> Result<S, CalibError> {
        self.ticks.finish()
    }

    /// Ends the loop (its switch-off), keeping the recorder (to report after an error).
    pub fn switch_off(&mut self) -> Result<(), CalibError> {
        self.ticks.switch_off()
    }

    fn ticks_of(&self, s: f64) -> usize {
        (s / self.rig.period_s).round().max(1.0) as usize
    }

    /// Waits until the hand's grip is still, then averages its counts: over `average_s`, or longer
    /// (up to `max_average_s`) when the noise at rest is high, until the average is known to
    /// `target_sem_m`. `None`: not still before the timeout (the operator was told).
    fn still_average(
        &mut self,
        hand: usize,
        tell: &mut dyn FnMut(&str),
    ) -> Result<Option<Still>, CalibError> {
        let mpc = self.rig.hands[hand].metres_per_count;
        let window = self.ticks_of(self.opts.still_window_s);
        let avg = self.ticks_of(self.opts.average_s);
        let max_avg = self.ticks_of(self.opts.max_average_s).max(avg);
        let block = self.ticks_of(self.opts.block_s);
        let timeout = self.ticks_of(self.opts.timeout_s);
        let range_counts: [f64; 4] = std::array::from_fn(|i| self.opts.still_range_m / mpc[i].abs());
        let mut recent: VecDeque<[i64; 4]> = VecDeque::with_capacity(window + max_avg + 1);
        for tick in 0..timeout {
            // A tick the loop did not take (late, bad, jumped, faulted) leaves its sample out.
            let Some(counts) = self.ticks.tick()?.hands[hand] else { continue };
            recent.push_back(counts);
            if recent.len() > window + max_avg {
                recent.pop_front();
            }
            // Judged once per block, once the buffer holds the window plus the shortest average.
            if recent.len() < window + avg || tick % block != 0 {
                continue;
            }
            let buf = recent.make_contiguous();
            // The noise of the latest samples (older ones may be from the reach to this pose).
            let sigma = noise_counts(&buf[buf.len() - window - avg..]);
            let need = (0..4)
                .map(|i| (sigma[i] * mpc[i].abs() / self.opts.target_sem_m).powi(2).ceil() as usize)
                .max()
                .unwrap_or(avg)
                .clamp(avg, max_avg);
            if buf.len() < window + need {
                continue;
            }
            let span = &buf[buf.len() - window - need..];
            if is_still(span, block, &range_counts) {
                let tail = &span[window..];
                let n = tail.len() as f64;
                let counts: [f64; 4] =
                    std::array::from_fn(|i| tail.iter().map(|s| s[i] as f64).sum::<f64>() / n);
                let counts_std: [f64; 4] = std::array::from_fn(|i| {
                    (tail.iter().map(|s| (s[i] as f64 - counts[i]).powi(2)).sum::<f64>() / (n - 1.0).max(1.0))
                        .sqrt()
                });
                return Ok(Some(Still { counts, counts_std, samples: tail.len() as u32 }));
            }
        }
        let line = format!(
            "hand {hand}: the grip did not keep still (within {:.1} mm beyond the noise for {:.1} s) in {:.0} s: \
             the pose is not kept; hold it steady, or rest it on the jig",
            self.opts.still_range_m * 1e3,
            self.opts.still_window_s + self.opts.average_s,
            self.opts.timeout_s
        );
        self.warn(tell, line);
        Ok(None)
    }

    fn warn(&mut self, tell: &mut dyn FnMut(&str), line: String) {
        tell(&format!("  warning: {line}"));
        self.warnings.push(line);
    }

    /// Records one pose. `Ok(None)`: skipped, or refused (the reason was told); ask for another.
    pub fn record_pose<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        hand: usize,
        req: &Request,
        earlier: &[PoseRecord],
    ) -> Result<Option<PoseRecord>, CalibError> {
        check_hand(hand)?;
        if op.request(&mut self.ticks, hand, req)? == Answer::Skip {
            op.tell("  skipped");
            return Ok(None);
        }
        let Some(Still { counts, counts_std, samples }) = self.still_average(hand, &mut |s| op.tell(s))?
        else {
            return Ok(None);
        };
        let mut tell = |s: &str| op.tell(s);
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
        for (k, e) in earlier.iter().filter(|e| e.hand == hand).enumerate() {
            let d2: f64 = (0..4).map(|i| ((counts[i] - e.counts[i]) * hr.metres_per_count[i]).powi(2)).sum();
            let d = (d2 / 4.0).sqrt();
            if d < self.opts.min_separation_m {
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
                    self.warn(&mut tell, line);
                }
                _ => {}
            }
        }
        let worst_um = (0..4).map(|i| spread_m[i]).fold(0.0, f64::max) * 1e6;
        op.tell(&format!("  recorded: {samples} samples, worst string spread {worst_um:.0} um"));
        Ok(Some(PoseRecord { hand, kind, counts, counts_std, samples }))
    }

    /// Records a home or jig point (which cannot be skipped), asking again while it is refused,
    /// up to `attempts` times.
    fn record_required<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        hand: usize,
        req: &Request,
        earlier: &[PoseRecord],
    ) -> Result<PoseRecord, CalibError> {
        for attempt in 1..=self.opts.attempts {
            if let Some(p) = self.record_pose(op, hand, req, earlier)? {
                return Ok(p);
            }
            if attempt < self.opts.attempts {
                op.tell(&format!("  again ({}/{}): {req}", attempt + 1, self.opts.attempts));
            }
        }
        Err(CalibError::Recording(format!(
            "hand {hand}: {req}: refused {} times (see the warnings); what was recorded is kept",
            self.opts.attempts
        )))
    }

    /// Records a whole plan into `session`, telling progress and handing the session to `save`
    /// after every kept pose. Poses `session` already has are not asked again (a resumed session:
    /// the counters are checked at the home point first). Free poses that are refused are
    /// replaced by the next suggestion (at most twice as many attempts as poses asked for).
    /// On any error `session` holds every pose kept so far (and `save` has seen them).
    pub fn record_plan<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        plan: &Plan,
        session: &mut SessionFile,
        save: &mut dyn FnMut(&SessionFile) -> Result<(), CalibError>,
    ) -> Result<(), CalibError> {
        // Hands, counts and box in range (whether the poses will be enough for a fit is
        // [`Plan::check`], for the command line: a test may record a partial plan).
        plan.session_plan(None).check().map_err(CalibError::Options)?;
        for &hand in &plan.hands {
            let hr = &self.rig.hands[hand];
            let home = Request::Home { at_m: hr.home_m };
            let jig: Vec<_> = plan
                .jig
                .iter()
                .flat_map(|j| j.fit_points.iter())
                .filter(|p| p.hand == hand)
                .cloned()
                .collect();
            let total = 1 + jig.len() + plan.free_per_hand;
            let mut done = session.poses_of(hand).count();
            if done == 0 {
                op.tell(&format!(
                    "hand {hand} ({}): {total} poses: home, {} jig points, {} free poses",
                    hr.label,
                    jig.len(),
                    plan.free_per_hand
                ));
                op.tell(&format!("[1/{total}] {home}"));
                let p = self.record_required(op, hand, &home, &session.poses)?;
                keep(session, p, save)?;
                done = 1;
            } else {
                self.check_resume(op, hand, session)?;
                op.tell(&format!("hand {hand} ({}): resuming at pose {}/{total}", hr.label, done + 1));
            }
            for jp in &jig {
                let recorded = session
                    .poses_of(hand)
                    .any(|p| matches!(&p.kind, PoseKind::Jig { label, .. } if *label == jp.label));
                if recorded {
                    continue;
                }
                let req = Request::Jig { label: jp.label.clone(), at_m: jp.at() };
                op.tell(&format!("[{}/{total}] {req}", done + 1));
                let p = self.record_required(op, hand, &req, &session.poses)?;
                keep(session, p, save)?;
                done += 1;
            }
            // Twice as many suggestions as poses, so refused ones are replaced; a resumed session
            // goes on from the suggestion after its last kept free pose.
            let mut kept = session.poses_of(hand).filter(|p| p.kind == PoseKind::Free).count();
            let extended = Plan { free_per_hand: plan.free_per_hand * 2, ..plan.clone() };
            for s in extended.free_suggestions(self.rig, hand).into_iter().skip(kept) {
                if kept >= plan.free_per_hand {
                    break;
                }
                let req = Request::Free { index: kept, of: plan.free_per_hand, suggest_m: s };
                op.tell(&format!("[{}/{total}] {req}", done + 1));
                if let Some(p) = self.record_pose(op, hand, &req, &session.poses)? {
                    keep(session, p, save)?;
                    kept += 1;
                    done += 1;
                }
            }
            if kept < plan.free_per_hand {
                let line = format!("hand {hand}: only {kept} of {} free poses were kept", plan.free_per_hand);
                self.warn(&mut |s| op.tell(s), line);
            }
            // Back home, so the grip is where the next hand's operator expects it.
            op.request(&mut self.ticks, hand, &home)?;
        }
        Ok(())
    }

    /// Records `plan` into a new session kept in memory only (tests, benchmarks; the command
    /// line saves after every pose with [`Recorder::record_plan`]).
    pub fn record_session<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        plan: &Plan,
        device_name: &str,
    ) -> Result<SessionFile, CalibError> {
        let mut session = SessionFile::new(&self.rig.name, "", device_name, plan.session_plan(None));
        self.record_plan(op, plan, &mut session, &mut |_| Ok(()))?;
        session.complete = true;
        Ok(session)
    }

    /// A resumed hand: the grip back at the home point must read the lengths of the session's
    /// home pose, or the counters are not the ones the session was recorded with.
    fn check_resume<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        hand: usize,
        session: &SessionFile,
    ) -> Result<(), CalibError> {
        let hr = &self.rig.hands[hand];
        let Some(home) = session.poses_of(hand).find(|p| matches!(p.kind, PoseKind::Home { .. })) else {
            return Err(CalibError::Recording(format!(
                "hand {hand}: the session has poses of this hand but no home pose: it cannot be resumed; \
                 start a new session"
            )));
        };
        let PoseKind::Home { at_m } = home.kind else { unreachable!("filtered above") };
        op.tell(&format!(
            "hand {hand}: resuming; first the counters are checked at the home point (as recorded)"
        ));
        let (counts, _) = self.record_at(op, hand, &Request::Home { at_m: DVec3::from_array(at_m) })?;
        let d2: f64 = (0..4).map(|i| ((counts[i] - home.counts[i]) * hr.metres_per_count[i]).powi(2)).sum();
        let offset = (d2 / 4.0).sqrt();
        if offset > self.opts.resume_max_offset_m {
            return Err(CalibError::Recording(format!(
                "hand {hand}: at the home point the strings read {:.1} mm (RMS) from the session's home pose (limit \
                 {:.1} mm): the counters restarted (the board was power-cycled or reconnected) or the grip is not at \
                 home. Hold it at home and resume again, or start a new session without --resume",
                offset * 1e3,
                self.opts.resume_max_offset_m * 1e3
            )));
        }
        op.tell(&format!("  counters as recorded (home within {:.1} mm RMS)", offset * 1e3));
        if self.check_geometry[hand].is_none() {
            self.check_geometry[hand] = Some(HandGeometry::homed(hr, &home.counts, DVec3::from_array(at_m)));
        }
        Ok(())
    }

    /// Records the grip at `req` without the checks (homing, verification), asking again while
    /// it does not keep still (up to `attempts` times).
    pub fn record_at<O: Operator<S> + ?Sized>(
        &mut self,
        op: &mut O,
        hand: usize,
        req: &Request,
    ) -> Result<([f64; 4], [f64; 4]), CalibError> {
        check_hand(hand)?;
        for attempt in 1..=self.opts.attempts {
            if op.request(&mut self.ticks, hand, req)? == Answer::Skip {
                return Err(CalibError::Recording(format!(
                    "hand {hand}: {req}: this point cannot be skipped"
                )));
            }
            if let Some(s) = self.still_average(hand, &mut |l| op.tell(l))? {
                return Ok((s.counts, s.counts_std));
            }
            if attempt < self.opts.attempts {
                op.tell(&format!("  again ({}/{}): {req}", attempt + 1, self.opts.attempts));
            }
        }
        Err(CalibError::Recording(format!(
            "hand {hand}: {req}: the grip did not keep still in {} tries: hold it steady, or rest it on the jig",
            self.opts.attempts
        )))
    }
}

fn check_hand(hand: usize) -> Result<(), CalibError> {
    if hand > 1 {
        return Err(CalibError::Options(format!("hand {hand}: must be 0 (left) or 1 (right)")));
    }
    Ok(())
}

/// Adds a pose to the session and saves it.
fn keep(
    session: &mut SessionFile,
    p: PoseRecord,
    save: &mut dyn FnMut(&SessionFile) -> Result<(), CalibError>,
) -> Result<(), CalibError> {
    session.poses.push(p);
    session.recorded_utc = crate::utc_now();
    save(session)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples of one string's counts: a value, gaussian-ish noise (sum of uniforms), a ramp.
    fn samples(n: usize, noise: f64, ramp_per_sample: f64, seed: u64) -> Vec<[i64; 4]> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed);
        (0..n)
            .map(|k| {
                std::array::from_fn(|_| {
                    let z: f64 = (0..12).map(|_| rng.random_range(0.0..1.0)).sum::<f64>() - 6.0;
                    (1000.0 + k as f64 * ramp_per_sample + noise * z).floor() as i64
                })
            })
            .collect()
    }

    #[test]
    fn thresholds_out_of_range_are_refused_by_name() {
        RecordOptions::default().check().unwrap();
        for (o, says) in [
            (RecordOptions { still_range_m: f64::NAN, ..RecordOptions::default() }, "stillness range"),
            (RecordOptions { average_s: -1.0, ..RecordOptions::default() }, "averaging time"),
            (RecordOptions { lost_after_s: f64::INFINITY, ..RecordOptions::default() }, "board-lost time"),
            (RecordOptions { attempts: 0, ..RecordOptions::default() }, "attempts"),
            (RecordOptions { max_average_s: 0.1, ..RecordOptions::default() }, "longest averaging"),
        ] {
            let e = o.check().unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
        let plan = |hands: Vec<usize>, free| Plan {
            hands,
            jig: None,
            free_per_hand: free,
            free_half_extent_m: DVec3::splat(0.3),
        };
        assert!(plan(vec![0, 1], 17).check().is_ok());
        assert!(plan(vec![0, 1], 16).check().unwrap_err().to_string().contains("at least 17"));
        assert!(plan(vec![2], 40).check().unwrap_err().to_string().contains("hand 2"));
        assert!(plan(vec![0, 0], 40).check().unwrap_err().to_string().contains("twice"));
    }

    #[test]
    fn three_counts_of_noise_are_still_and_a_moving_grip_is_not() {
        // 0.5 mm at 2.9e-5 m per count: 17 counts.
        let range = [17.0; 4];
        let mut raw_too_wide = 0;
        for seed in 0..20 {
            let still = samples(800, 3.0, 0.0, seed);
            assert!(is_still(&still, 50, &range), "3 counts of noise, seed {seed}");
            assert!(is_still(&samples(800, 0.0, 0.0, seed), 50, &range), "no noise");
            // Judged sample by sample, the noise alone spans more than the range.
            let (lo, hi) = still.iter().fold((i64::MAX, i64::MIN), |(l, h), s| (l.min(s[0]), h.max(s[0])));
            raw_too_wide += usize::from(hi - lo > 17);
            // Moving 1.5 mm/s (52 counts over 0.8 s) with the same noise: not still.
            assert!(!is_still(&samples(800, 3.0, 0.065, seed), 50, &range), "a moving grip, seed {seed}");
        }
        assert!(raw_too_wide >= 15, "the raw spread exceeded the range in only {raw_too_wide} of 20");
        // A slow drift well inside the range is still.
        assert!(is_still(&samples(800, 3.0, 0.01, 1), 50, &range));
    }
}

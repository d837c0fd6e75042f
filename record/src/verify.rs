//! `spidar replay --verify`: re-runs the rt-loop's tick core from a recording's inputs and checks
//! that it computes exactly what was recorded.
//!
//! Per recorded tick, in the order the loop gives them (see `spidar_rt::runner`): the commands,
//! the contact model taken, a device reopen, then one [`TickCore::step`] with the recorded device
//! input, the exchange's error and the wake-up time. The tick message it produces (lifecycle,
//! fault, gain, hands, forces, tensions, volts) and the hand sample must be byte-identical to the
//! recorded ones, and so must the events it reports. The first difference is named with its tick
//! and field. The core is built from the rig file attached to the recording, or from another
//! rig file to see what it would change.

use std::path::Path;

use spidar_device::{DeviceError, ErrorKind, Output};
use spidar_msg::HandSample;
use spidar_rt::telemetry::TickRecord;
use spidar_rt::{Event, Rig, TickCore};

use crate::cdr::{self, Field};
use crate::reader::{self, Flow, Msg, Recording};
use crate::schema::{EventMsg, TakenModel};
use crate::RecordError;

/// The first place the re-run differs from the recording.
#[derive(Clone, Debug, PartialEq)]
pub struct Difference {
    pub tick: u64,
    pub t_s: f64,
    pub what: String,
}

/// What `verify` found.
#[derive(Clone, Debug)]
pub struct VerifyReport {
    pub recording: Recording,
    /// Where the rig file came from.
    pub rig: String,
    /// Ticks re-run and found identical.
    pub ticks_identical: u64,
    pub samples_identical: u64,
    pub first_difference: Option<Difference>,
    /// Ticks missing from the recording, after which nothing can be checked.
    pub gap_at: Option<u64>,
}

impl VerifyReport {
    pub fn passed(&self) -> bool {
        self.first_difference.is_none() && self.gap_at.is_none() && self.ticks_identical > 0
    }
}

impl std::fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let r = &self.recording;
        writeln!(f, "replay --verify {} with rig {}", r.path.display(), self.rig)?;
        match (&self.first_difference, self.gap_at) {
            (Some(d), _) => writeln!(
                f,
                "  DIFFERS      at tick {} (t = {:.3} s): {}\n               {} ticks before it were identical",
                d.tick, d.t_s, d.what, self.ticks_identical
            )?,
            (None, Some(g)) => writeln!(
                f,
                "  INCOMPLETE   ticks are missing from tick {g} on (dropped while recording): {} ticks before it were identical",
                self.ticks_identical
            )?,
            (None, None) if self.ticks_identical == 0 => writeln!(f, "  NOTHING      the recording holds no tick")?,
            (None, None) => writeln!(
                f,
                "  identical    {} ticks and {} hand samples bit for bit (volts, forces, tensions, lifecycle, events)",
                self.ticks_identical, self.samples_identical
            )?,
        }
        write!(f, "  recording    {}", r.ends())
    }
}

/// The error the device gave, rebuilt from its recorded kind (the core reacts to the kind only).
fn device_error(k: ErrorKind) -> DeviceError {
    const WHAT: &str = "replayed from a recording";
    match k {
        ErrorKind::Timeout => DeviceError::Timeout { waited_us: 0 },
        ErrorKind::Corrupt => DeviceError::Corrupt { what: WHAT },
        ErrorKind::Disconnected => DeviceError::Disconnected { what: WHAT },
        ErrorKind::Protocol => DeviceError::Protocol { what: WHAT },
        ErrorKind::Other => DeviceError::Other { what: WHAT },
    }
}

/// Names the first field where two encodings of a `T` differ, with both values.
pub fn first_field_difference<T: Field>(recorded: &T, replayed: &T) -> Option<String> {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    cdr::encode(recorded, &mut a);
    cdr::encode(replayed, &mut b);
    if a == b {
        return None;
    }
    let mut cols = Vec::new();
    T::columns("", &mut cols);
    let (mut ca, mut cb) = (String::new(), String::new());
    recorded.csv(&mut ca);
    replayed.csv(&mut cb);
    let found = cols.iter().zip(ca.split(',').skip(1).zip(cb.split(',').skip(1))).find(|(_, (x, y))| x != y);
    Some(match found {
        Some((col, (x, y))) => format!("{col}: recorded {x}, replayed {y}"),
        None => "the encodings differ (a NaN's payload)".into(),
    })
}

/// The tick core for the first recorded tick `t`: built from `rig` (origin, text) or the rig file
/// attached to the recording, its counters taken from the tick's input.
fn first_core(
    rec: &crate::reader::Recording,
    path: &Path,
    rig: Option<(String, String)>,
    t: &TickRecord,
) -> Result<(TickCore, String), String> {
    let (origin, text) = match rig {
        Some(r) => r,
        None => match rec.rig_text() {
            Some(text) => (format!("rig.ron attached to {}", path.display()), text),
            None => return Err("the recording has no rig file attached: pass one with --rig".into()),
        },
    };
    let mut c = Rig::from_str(&text, &origin)
        .map_err(|e| e.to_string())
        .and_then(|r| TickCore::new(&r).map_err(|e| e.to_string()))
        .map_err(|e| format!("the rig file does not load: {e}"))?;
    c.observe_counts(&t.input);
    Ok((c, origin))
}

/// Re-runs recorded tick `t` on `c` with what went into it (commands, the contact model taken,
/// a reopen, a device error) and compares what came out with the recording: every field of the
/// tick's record, then its events (taken from `events`). The replayed hand sample, or the first
/// difference.
fn replay_tick(
    c: &mut TickCore,
    t: &TickRecord,
    model: Option<TakenModel>,
    events: &mut Vec<EventMsg>,
) -> Result<HandSample, Difference> {
    for cmd in t.commands.iter() {
        c.command(cmd);
    }
    if let Some(m) = model {
        c.set_contact_model(m.model);
    }
    if t.reopened {
        c.device_reopened();
    }
    let io = t.io_error.map_or(Ok(()), |k| Err(device_error(k)));
    let (mut out, mut sample, mut r) = (Output::default(), HandSample::default(), TickRecord::default());
    c.step(t.t_s, io, &t.input, &mut out, &mut sample, &mut r);
    // What is not the core's to compute comes from the recording.
    r.lateness_s = t.lateness_s;
    r.compute_s = t.compute_s;
    r.io_s = t.io_s;
    r.commands = t.commands;
    r.reopened = t.reopened;
    r.io_error = t.io_error;
    r.input = t.input;
    r.output = out;
    let fail = |what: String| Difference { tick: t.tick, t_s: t.t_s, what };
    if let Some(d) = first_field_difference(t, &r) {
        return Err(fail(d));
    }
    let mine: Vec<EventMsg> = std::iter::from_fn(|| c.pop_event())
        .filter(|e| !matches!(e, Event::Stopped))
        .map(|e| EventMsg::new(t.tick, t.t_s, &e))
        .collect();
    let theirs: Vec<EventMsg> = events.drain(..).filter(|e| e.tick == t.tick).collect();
    if mine != theirs {
        let names = |v: &[EventMsg]| v.iter().map(|e| e.text.clone()).collect::<Vec<_>>().join("; ");
        return Err(fail(format!("events: recorded [{}], replayed [{}]", names(&theirs), names(&mine))));
    }
    Ok(sample)
}

/// Re-runs the tick core over the recording at `path`. `rig`: (origin, text) of another rig file
/// to use instead of the attached one.
pub fn verify(path: &Path, rig: Option<(String, String)>) -> Result<VerifyReport, RecordError> {
    let mut core: Option<TickCore> = None;
    let mut rig_origin = String::new();
    let mut model: Option<TakenModel> = None;
    let mut events: Vec<EventMsg> = Vec::new();
    let mut replayed_sample: Option<(u64, HandSample)> = None;
    let mut next_tick: Option<u64> = None;
    let (mut ticks_ok, mut samples_ok) = (0u64, 0u64);
    let mut diff: Option<Difference> = None;
    let mut gap_at = None;
    let mut setup_err = None;

    let rec = reader::read(path, |rec, msg| {
        match msg {
            Msg::Model(m) => model = Some(*m),
            Msg::Event(e) => {
                if e.kind != 6 {
                    events.push(e); // `stopped` is the loop's, not the core's
                }
            }
            Msg::Tick(t) => {
                if next_tick.is_some_and(|n| n != t.tick) {
                    gap_at = next_tick;
                    return Ok(Flow::Stop);
                }
                next_tick = Some(t.tick + 1);
                if core.is_none() {
                    match first_core(rec, path, rig.clone(), &t) {
                        Ok((c, origin)) => (core, rig_origin) = (Some(c), origin),
                        Err(why) => {
                            setup_err = Some(why);
                            return Ok(Flow::Stop);
                        }
                    }
                }
                let Some(c) = core.as_mut() else { return Ok(Flow::Stop) };
                let m = model.take().filter(|m| m.tick == t.tick);
                match replay_tick(c, &t, m, &mut events) {
                    Ok(sample) => {
                        ticks_ok += 1;
                        replayed_sample = Some((t.tick, sample));
                    }
                    Err(d) => {
                        diff = Some(d);
                        return Ok(Flow::Stop);
                    }
                }
            }
            Msg::Sample(s) => {
                if let Some((tick, mine)) = replayed_sample.take().filter(|(tick, _)| *tick == s.tick) {
                    if let Some(d) = first_field_difference(s.as_ref(), &mine) {
                        diff = Some(Difference { tick, t_s: s.t_s, what: format!("hand sample: {d}") });
                        return Ok(Flow::Stop);
                    }
                    samples_ok += 1;
                }
            }
            Msg::Other { .. } => {}
        }
        Ok(Flow::Continue)
    })?;
    if let Some(why) = setup_err {
        return Err(RecordError::Replay { path: path.to_path_buf(), why });
    }
    Ok(VerifyReport {
        recording: rec,
        rig: rig_origin,
        ticks_identical: ticks_ok,
        samples_identical: samples_ok,
        first_difference: diff,
        gap_at,
    })
}

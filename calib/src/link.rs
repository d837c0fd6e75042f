//! The device as calibration drives it: every string held at the rig's minimum tension, one
//! exchange per tick, late or bad replies retried and counted, garbled counts left out, a stop
//! request and a lasting loss of the board turned into errors that end the session cleanly.
//!
//! Why it exists: a guided session lasts minutes and a person moves the grip all along. A board
//! reply that comes after its deadline, or one corrupted byte, must not throw that work away:
//! the sample of that tick is left out, the exchange is retried on the next tick, and the
//! session goes on. Only when the board stays silent for `lost_after_s`, or the link is gone,
//! does the session stop (what was recorded is kept by the caller). A stop signal (Ctrl-C,
//! SIGTERM) is polled every tick.
//!
//! UART replies carry no checksum, so a garbled byte can change a count by up to 4096 (12 cm of
//! string) while the exchange reports success. Averaged into a pose, one such count moves the
//! pose's mean by millimetres with nothing to show for it. So a reply whose count on any string of
//! the rig steps by more than the rig's `reply_jump_m` (2 mm: a grip moved by hand moves less in
//! one tick) from the last reply taken is left out and counted, like a late one. A real step (a
//! string that slipped, a grip moved faster) persists: a reply that agrees within the same
//! tolerance with the reply left out just before it is taken, and the step with it.
//!
//! What it must never do: command anything but the holding output (every string at minimum
//! tension), or stall without commanding the boards: they have no watchdog and hold their last
//! command, so the holding output is what they keep if this program dies.

use std::sync::Arc;
use std::time::{Duration, Instant};

use spidar_device::{Device, ErrorKind, Input, Output, MAX_CHANNELS};
use spidar_rt::Rig;

use crate::CalibError;

/// Times the switch-off is tried when its replies come late or bad.
const SWITCH_OFF_ATTEMPTS: u32 = 20;

/// Polled every tick: `true` asks the session to stop (outputs off, what was recorded kept).
pub type StopCheck = Arc<dyn Fn() -> bool + Send + Sync>;

/// What the link saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Exchanges that succeeded.
    pub exchanges: u64,
    /// Exchanges that failed (a late, lost or corrupt reply) and were retried on the next tick.
    pub retried: u64,
    /// Longest run of failed exchanges in a row.
    pub longest_outage_ticks: u64,
    /// Replies left out because a count stepped by more than `reply_jump_m` (garbled counts).
    pub count_jumps: u64,
}

impl std::fmt::Display for LinkStats {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} exchanges, {} late or bad replies retried (longest outage {} ticks), {} replies with a count \
             jump left out",
            self.exchanges, self.retried, self.longest_outage_ticks, self.count_jumps
        )
    }
}

/// The output that holds every string of the rig at its minimum tension: what the device gets
/// all through calibration, also while the operator moves the grip.
pub fn holding_output(rig: &Rig) -> Output {
    let mut out = Output::default();
    for hr in &rig.hands {
        for i in 0..4 {
            out.volts[hr.channels[i]] = hr.tension_min_n * hr.volts_per_newton[i];
        }
    }
    out
}

/// Per channel, `reply_jump_m` in counts for the rig's strings (at least one count), 0 elsewhere.
fn jump_counts(rig: &Rig) -> [i64; MAX_CHANNELS] {
    let mut j = [0; MAX_CHANNELS];
    for hr in &rig.hands {
        for i in 0..4 {
            j[hr.channels[i]] =
                (rig.safety.reply_jump_m / hr.metres_per_count[i].abs()).ceil().max(1.0) as i64;
        }
    }
    j
}

/// The device with calibration's exchange policy.
pub struct Link<D: Device> {
    dev: D,
    out: Output,
    inp: Input,
    period: Duration,
    /// Pace exchanges by the wall clock (a real board); `false`: back to back (the simulated
    /// rig, whose time is its exchange count).
    pace: bool,
    next: Option<Instant>,
    lost_after_ticks: u64,
    failed_in_a_row: u64,
    stop: Option<StopCheck>,
    stats: LinkStats,
    /// Per channel: the largest count step taken from one reply to the next (0: not a string
    /// of the rig, not checked).
    jump_counts: [i64; MAX_CHANNELS],
    /// The last reply taken, and the last one left out for a count jump (if the latest was).
    taken: Option<Input>,
    left_out: Option<Input>,
}

impl<D: Device> Link<D> {
    /// `dev` opened already. Activates it (strings at minimum tension from the first exchange).
    /// The board counts as lost after `lost_after_s` without a good exchange.
    pub fn activate(mut dev: D, rig: &Rig, pace: bool, lost_after_s: f64) -> Result<Link<D>, CalibError> {
        dev.activate()?;
        let period = Duration::from_secs_f64(rig.period_s);
        Ok(Link {
            dev,
            out: holding_output(rig),
            inp: Input::default(),
            period,
            pace,
            next: None,
            lost_after_ticks: (lost_after_s / rig.period_s).ceil().max(1.0) as u64,
            failed_in_a_row: 0,
            stop: None,
            stats: LinkStats::default(),
            jump_counts: jump_counts(rig),
            taken: None,
            left_out: None,
        })
    }

    /// Polls `stop` every tick from now on.
    pub fn set_stop(&mut self, stop: StopCheck) {
        self.stop = Some(stop);
    }

    pub fn device(&mut self) -> &mut D {
        &mut self.dev
    }

    pub fn stats(&self) -> LinkStats {
        self.stats
    }

    /// True once a stop was asked for.
    pub fn stop_requested(&self) -> bool {
        self.stop.as_ref().is_some_and(|s| s())
    }

    /// One tick: waits for its time (when paced), exchanges the holding output, and returns the
    /// counts, or `None` when this tick's reply was late or bad (counted; retried next tick).
    /// Errors: a stop request, a lost board (disconnected, or silent for `lost_after_s`).
    pub fn tick(&mut self) -> Result<Option<&Input>, CalibError> {
        if self.stop_requested() {
            return Err(CalibError::Interrupted("a stop signal (Ctrl-C, SIGTERM or SIGHUP)".into()));
        }
        if self.pace {
            let now = Instant::now();
            let next = self.next.map_or(now, |t| t + self.period);
            if next > now {
                std::thread::sleep(next - now);
                self.next = Some(next);
            } else {
                // Behind (a slow exchange): no burst to catch up, the next tick a period from now.
                self.next = Some(now);
            }
        }
        match self.dev.exchange(&self.out, &mut self.inp) {
            Ok(()) => {
                self.stats.exchanges += 1;
                self.failed_in_a_row = 0;
                let near = |a: &Input| self.within_step(a, &self.inp);
                if self.taken.as_ref().is_none_or(near) || self.left_out.as_ref().is_some_and(near) {
                    self.taken = Some(self.inp);
                    self.left_out = None;
                    Ok(Some(&self.inp))
                } else {
                    self.stats.count_jumps += 1;
                    self.left_out = Some(self.inp);
                    Ok(None)
                }
            }
            Err(e) if e.kind() == ErrorKind::Disconnected => Err(CalibError::BoardLost(format!(
                "{e}; the board is gone (unplugged, powered down, or the emulator stopped)"
            ))),
            Err(e) => {
                self.stats.retried += 1;
                self.failed_in_a_row += 1;
                self.stats.longest_outage_ticks = self.stats.longest_outage_ticks.max(self.failed_in_a_row);
                if self.failed_in_a_row >= self.lost_after_ticks {
                    return Err(CalibError::BoardLost(format!(
                        "no good reply for {} ticks ({:.1} s; last: {e}): check the cable and the board's power",
                        self.failed_in_a_row,
                        self.failed_in_a_row as f64 * self.period.as_secs_f64()
                    )));
                }
                Ok(None)
            }
        }
    }

    /// True when no checked count of `b` is further than its step from `a`'s.
    fn within_step(&self, a: &Input, b: &Input) -> bool {
        (0..MAX_CHANNELS)
            .all(|k| self.jump_counts[k] == 0 || (b.counts[k] - a.counts[k]).abs() <= self.jump_counts[k])
    }

    /// Switches the outputs off (one last holding exchange first, so a board that missed
    /// commands gets a sane one before the zero). A late or bad reply to the switch-off is
    /// retried like any other (up to `SWITCH_OFF_ATTEMPTS` ticks): an error here means the zero
    /// may not have reached the boards.
    pub fn switch_off(&mut self) -> Result<(), CalibError> {
        let _ = self.dev.exchange(&self.out, &mut self.inp);
        let mut attempt = 0;
        loop {
            match self.dev.deactivate() {
                Ok(()) => return Ok(()),
                Err(e) if e.kind() != ErrorKind::Disconnected && attempt + 1 < SWITCH_OFF_ATTEMPTS => {
                    attempt += 1;
                    self.stats.retried += 1;
                    if self.pace {
                        std::thread::sleep(self.period);
                    }
                }
                Err(e) => return Err(e.into()),
            }
        }
    }

    /// Switches the outputs off and hands the device back.
    pub fn finish(mut self) -> Result<D, CalibError> {
        self.switch_off()?;
        Ok(self.dev)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use spidar_device::{DeviceError, DeviceInfo};

    /// Replies with the next of `counts` on channel 0 (every other channel 0).
    struct Scripted {
        counts: Vec<i64>,
        next: usize,
        info: DeviceInfo,
    }

    impl Device for Scripted {
        fn open(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn activate(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn deactivate(&mut self) -> Result<(), DeviceError> {
            Ok(())
        }
        fn exchange(&mut self, _: &Output, inp: &mut Input) -> Result<(), DeviceError> {
            *inp = Input::default();
            inp.counts[0] = self.counts[self.next];
            self.next += 1;
            Ok(())
        }
        fn info(&self) -> &DeviceInfo {
            &self.info
        }
    }

    #[test]
    fn a_garbled_count_is_left_out_and_a_step_that_persists_is_taken() {
        let rig = Rig::default_rig();
        // The built-in rig's 2 mm step is about 69 counts on channel 0.
        let step = jump_counts(&rig)[0];
        assert!((60..80).contains(&step), "{step}");
        let counts = vec![0, 30, 4000, 35, 60, 60 + step + 1, 60, 500, 510, 520, 1000];
        let taken = [true, true, false, true, true, false, true, false, true, true, false];
        let info = DeviceInfo {
            board: Default::default(),
            identity: Default::default(),
            channels: 8,
            volts_min: -10.0,
            volts_max: 10.0,
        };
        let dev = Scripted { counts: counts.clone(), next: 0, info };
        let mut link = Link::activate(dev, &rig, false, 2.0).unwrap();
        for (k, &want) in taken.iter().enumerate() {
            let got = link.tick().unwrap().map(|i| i.counts[0]);
            assert_eq!(got, want.then_some(counts[k]), "reply {k} ({})", counts[k]);
        }
        // A spike (4000), a step just over the limit that went back, a real step to 500 (taken
        // on its second reply, then followed), a jump at the end.
        assert_eq!(link.stats().count_jumps, 4);
        assert_eq!(link.stats().retried, 0, "a count jump is not a late reply");
    }
}

//! A person at a terminal as the calibration [`Operator`]: each request is printed in rig-frame
//! metres, and the person answers with Enter (the grip is there), `s` (skip this free pose) or
//! `q` (abort).
//!
//! Why it exists: on a real rig the grip is moved by hand, and the tool must wait for the person
//! without letting the boards go idle. While it waits it keeps exchanging with the device at the
//! tick period, every string held at the rig's minimum tension, and it watches for a stop signal:
//! the boards have no watchdog and hold whatever they were told last, so a tool that stopped
//! commanding them would leave them at its last command.
//!
//! What it must never do: block on the keyboard while the device needs commands (the keys are
//! read on their own thread), or leave the outputs on when the person aborts or the console
//! closes (it deactivates the device before returning [`CalibError::Aborted`]).

use std::io::{BufRead, Write};
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, TryRecvError};
use std::sync::Arc;
use std::time::Duration;

use spidar_device::{Device, ErrorKind, Input, Output};
use spidar_rt::Rig;

use crate::record::{holding_output, Answer, Operator, Request};
use crate::CalibError;

/// Consecutive failed exchanges (other than a disconnection) tolerated while waiting, as the
/// recorder tolerates them while recording.
const MAX_FAILED_EXCHANGES: u32 = 50;

/// The calibration operator at a console.
pub struct ConsoleOperator {
    keys: Receiver<String>,
    out: Box<dyn Write + Send>,
    hold: Output,
    scratch: Input,
    labels: [String; 2],
    tension_min_n: [f64; 2],
    /// Wait one tick period between exchanges (a real board); `None`: back to back (the simulated
    /// rig, whose time is its exchange count).
    period: Option<Duration>,
    /// Non-zero once a stop was asked for (a stop signal): abort with the outputs off.
    stop: Option<Arc<AtomicU32>>,
}

impl ConsoleOperator {
    /// Reads the answers from `keys` (one line each) on a thread of its own and writes prompts
    /// to `out`. `paced`: exchange once per tick period of `rig` while waiting.
    pub fn new<R: BufRead + Send + 'static>(
        keys: R,
        out: Box<dyn Write + Send>,
        rig: &Rig,
        paced: bool,
    ) -> Result<ConsoleOperator, CalibError> {
        let (tx, rx) = mpsc::channel();
        std::thread::Builder::new()
            .name("calib-keys".into())
            .spawn(move || {
                for line in keys.lines() {
                    // A read error ends the input like end of file: the operator aborts.
                    let Ok(line) = line else { break };
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            })
            .map_err(|source| CalibError::Io {
                file: "<console>".into(),
                what: "starting the key reader",
                source,
            })?;
        Ok(ConsoleOperator {
            keys: rx,
            out,
            hold: holding_output(rig),
            scratch: Input::default(),
            labels: [rig.hands[0].label.clone(), rig.hands[1].label.clone()],
            tension_min_n: [rig.hands[0].tension_min_n, rig.hands[1].tension_min_n],
            period: paced.then(|| Duration::from_secs_f64(rig.period_s)),
            stop: None,
        })
    }

    /// Aborts (outputs off) at the next wait once `stop` is non-zero (the stop signals counted).
    pub fn with_stop(mut self, stop: Arc<AtomicU32>) -> ConsoleOperator {
        self.stop = Some(stop);
        self
    }

    /// The terminal: keys from stdin, prompts on stderr (stdout keeps the results).
    pub fn stdio(rig: &Rig) -> Result<ConsoleOperator, CalibError> {
        ConsoleOperator::new(
            std::io::BufReader::new(std::io::stdin()),
            Box::new(std::io::stderr()),
            rig,
            true,
        )
    }

    /// What the person needs to know before the first request.
    pub fn introduce(&mut self) {
        let line = format!(
            "The strings are held at minimum tension ({:.1} N left, {:.1} N right) while you move the grips.\n\
             For each request: put the grip there, let go of any jig clamp's play, hold it still and press Enter;\n\
             the tool then waits until the grip is still and records (about a second).\n\
             Keys: Enter = the grip is there, s + Enter = skip this free pose, q + Enter = abort (outputs off).\n\
             The boards have no watchdog: if this program stalls or dies, the motors keep their last \
             command (minimum tension) until it ends or the boards are switched off; keep hold of the grip.",
            self.tension_min_n[0], self.tension_min_n[1]
        );
        self.say(&line);
    }

    fn say(&mut self, line: &str) {
        // A closed console is noticed on the key side; losing a prompt must not stop the rig safely
        // holding its strings.
        let _ = writeln!(self.out, "{line}");
        let _ = self.out.flush();
    }

    /// Holds the strings, switches the outputs off and reports why.
    fn abort<D: Device>(&mut self, dev: &mut D, why: &str) -> CalibError {
        let _ = dev.exchange(&self.hold, &mut self.scratch);
        let off = dev.deactivate();
        let note = match off {
            Ok(()) => "outputs switched off".to_string(),
            Err(e) => format!("switching the outputs off failed ({e}): power the amplifiers down"),
        };
        self.say(&format!("aborting: {why}; {note}; nothing recorded is saved"));
        CalibError::Aborted(format!("{why}; {note}"))
    }

    /// Waits one period (or not at all) for a key line; `Err(())`: the input closed.
    fn next_key(&mut self) -> Result<Option<String>, ()> {
        match self.period {
            Some(p) => match self.keys.recv_timeout(p) {
                Ok(l) => Ok(Some(l)),
                Err(RecvTimeoutError::Timeout) => Ok(None),
                Err(RecvTimeoutError::Disconnected) => Err(()),
            },
            None => match self.keys.try_recv() {
                Ok(l) => Ok(Some(l)),
                Err(TryRecvError::Empty) => Ok(None),
                Err(TryRecvError::Disconnected) => Err(()),
            },
        }
    }
}

impl<D: Device> Operator<D> for ConsoleOperator {
    fn request(&mut self, dev: &mut D, hand: usize, req: &Request) -> Result<Answer, CalibError> {
        let skippable = matches!(req, Request::Free { .. });
        let label = self.labels[hand].clone();
        self.say(&format!("> hand {hand} ({label}): {req}"));
        self.say(if skippable {
            "  press Enter when the grip is there and still (s: skip this pose, q: abort)"
        } else {
            "  press Enter when the grip is there and still (q: abort)"
        });
        let mut failures = 0u32;
        loop {
            if self.stop.as_ref().is_some_and(|s| s.load(Ordering::SeqCst) > 0) {
                return Err(self.abort(dev, "a stop signal (SIGINT, SIGTERM or SIGHUP)"));
            }
            match self.next_key() {
                Err(()) => return Err(self.abort(dev, "the console input closed")),
                Ok(None) => {}
                Ok(Some(line)) => match line.trim() {
                    "" => return Ok(Answer::Ready),
                    "s" | "S" if skippable => return Ok(Answer::Skip),
                    "s" | "S" => self
                        .say("  this point cannot be skipped: press Enter when the grip is there (q: abort)"),
                    "q" | "Q" => return Err(self.abort(dev, "stopped by the operator (q)")),
                    other => self.say(&format!(
                        "  '{other}' is not an answer: Enter = the grip is there{}, q = abort",
                        if skippable { ", s = skip" } else { "" }
                    )),
                },
            }
            // Keep the boards commanded while the person moves the grip.
            match dev.exchange(&self.hold, &mut self.scratch) {
                Ok(()) => failures = 0,
                Err(e) if e.kind() != ErrorKind::Disconnected && failures < MAX_FAILED_EXCHANGES => {
                    failures += 1
                }
                Err(e) => {
                    let why = format!("the device failed while waiting ({e})");
                    let _ = self.abort(dev, &why);
                    return Err(e.into());
                }
            }
        }
    }

    fn tell(&mut self, line: &str) {
        self.say(line);
    }
}

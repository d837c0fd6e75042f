//! A person at a terminal as the calibration [`Operator`]: each request is printed in rig-frame
//! metres, and the person answers with Enter (the grip is there), `s` (skip this free pose) or
//! `q` (abort).
//!
//! Why it exists: on a real rig the grip is moved by hand, and the tool must wait for the person
//! while the rt-loop holds the strings. While it waits it keeps reading the loop's [`Ticks`] (so
//! its records do not pile up, and a stop signal or a lost board is seen at once). The loop itself
//! runs on its own thread whatever this does, and on real boards its supervisor writes zero if
//! this process dies.
//!
//! What it must never do: block on the keyboard while the loop's records need reading (the keys
//! are read on their own thread), or leave the outputs on when the person aborts or the console
//! closes (it ends the loop, which switches them off, before returning [`CalibError::Aborted`]).

use std::io::{BufRead, Write};
use std::sync::mpsc::{self, Receiver, TryRecvError};

use spidar_rt::Rig;

use crate::record::{Answer, Operator, Request};
use crate::ticks::{TickSource, Ticks};
use crate::CalibError;

/// The calibration operator at a console.
pub struct ConsoleOperator {
    keys: Receiver<String>,
    out: Box<dyn Write + Send>,
    labels: [String; 2],
    tension_min_n: [f64; 2],
}

impl ConsoleOperator {
    /// Reads the answers from `keys` (one line each) on a thread of its own and writes prompts
    /// to `out`. While waiting it reads the loop's ticks as they come.
    pub fn new<R: BufRead + Send + 'static>(
        keys: R,
        out: Box<dyn Write + Send>,
        rig: &Rig,
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
            labels: [rig.hands[0].label.clone(), rig.hands[1].label.clone()],
            tension_min_n: [rig.hands[0].tension_min_n, rig.hands[1].tension_min_n],
        })
    }

    /// The terminal: keys from stdin, prompts on stderr (stdout keeps the results).
    pub fn stdio(rig: &Rig) -> Result<ConsoleOperator, CalibError> {
        ConsoleOperator::new(std::io::BufReader::new(std::io::stdin()), Box::new(std::io::stderr()), rig)
    }

    /// What the person needs to know before the first request.
    pub fn introduce(&mut self) {
        let line = format!(
            "The strings are held at minimum tension ({:.1} N left, {:.1} N right) while you move the grips.\n\
             For each request: put the grip there, let go of any jig clamp's play, hold it still and press Enter;\n\
             the tool then waits until the grip is still and records (about a second).\n\
             Keys: Enter = the grip is there, s + Enter = skip this free pose, q + Enter = abort (outputs off).\n\
             Ctrl-C switches the outputs off (`record` has saved every kept pose: continue it with --resume).\n\
             The rig's loop holds the strings as `spidar run` does; if this program dies, its supervisor \
             writes zero to the boards (they have no watchdog).",
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

    /// Ends the loop (outputs off) and reports why.
    fn abort<S: TickSource>(&mut self, ticks: &mut Ticks<S>, why: &str) -> CalibError {
        let note = match ticks.switch_off() {
            Ok(()) => "outputs switched off".to_string(),
            Err(e) => format!("switching the outputs off failed ({e}): power the amplifiers down"),
        };
        self.say(&format!("aborting: {why}; {note}"));
        CalibError::Aborted(format!("{why}; {note}"))
    }

    /// A key line if one came; `Err(())`: the input closed.
    fn next_key(&mut self) -> Result<Option<String>, ()> {
        match self.keys.try_recv() {
            Ok(l) => Ok(Some(l)),
            Err(TryRecvError::Empty) => Ok(None),
            Err(TryRecvError::Disconnected) => Err(()),
        }
    }
}

impl<S: TickSource> Operator<S> for ConsoleOperator {
    fn request(&mut self, ticks: &mut Ticks<S>, hand: usize, req: &Request) -> Result<Answer, CalibError> {
        let skippable = matches!(req, Request::Free { .. });
        let label = self.labels[hand].clone();
        self.say(&format!("> hand {hand} ({label}): {req}"));
        self.say(if skippable {
            "  press Enter when the grip is there and still (s: skip this pose, q: abort)"
        } else {
            "  press Enter when the grip is there and still (q: abort)"
        });
        loop {
            // Keep reading the loop while the person moves the grip (and see a stop signal).
            if let Err(e) = ticks.tick() {
                let _ = ticks.switch_off();
                self.say(&format!("stopping: {e}; outputs switched off"));
                return Err(e);
            }
            match self.next_key() {
                Err(()) => return Err(self.abort(ticks, "the console input closed")),
                Ok(None) => {}
                Ok(Some(line)) => match line.trim() {
                    "" => return Ok(Answer::Ready),
                    "s" | "S" if skippable => return Ok(Answer::Skip),
                    "s" | "S" => self
                        .say("  this point cannot be skipped: press Enter when the grip is there (q: abort)"),
                    "q" | "Q" => return Err(self.abort(ticks, "stopped by the operator (q)")),
                    other => self.say(&format!(
                        "  '{other}' is not an answer: Enter = the grip is there{}, q = abort",
                        if skippable { ", s = skip" } else { "" }
                    )),
                },
            }
        }
    }

    fn tell(&mut self, line: &str) {
        self.say(line);
    }
}

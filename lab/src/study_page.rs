//! The page of `spidar study reactions`: the live view's page and server ([`FedView`]) fed the
//! study's clips ([`crate::study`]), one participant at a time: the page asks for the
//! participant's id, then shows each clip once, in an order of that participant's own
//! ([`crate::study::order_for`]), at its recorded pace, and after each asks which part of the
//! virtual human was attacked (Table IV's four answers, as buttons). Each answer goes to the CSV
//! file as it comes.
//!
//! The study's state goes to the page as a `study` message (the whole state each time, also
//! four times a second, so a page that reconnects catches up): its phase (`welcome`, `ready`,
//! `playing`, `ask`, `done`), the participant, the clip's position in the order and its id, the
//! four answers. The page sends `{"cmd":"study-begin","participant":ID}` and
//! `{"cmd":"study-answer","index":K,"clip":ID,"answer":A,"response_s":S}`; an answer to another
//! question than the one asked is ignored (a double click, a stale page).
//!
//! Must never: take an answer for a clip not asked, or ask about a clip the participant has
//! not been shown whole.

use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde_json::{json, Value};
use spidar_world::view::{FedView, ViewOptions};

use crate::eval::TARGETS;
use crate::study::{check_participant, open_answers, order_for, Answer, Clips};

/// How long the virtual human stands in its guard before a clip plays.
const READY_S: f64 = 0.8;
/// How long the thanks show before the page asks for the next participant.
const DONE_S: f64 = 3.0;
const STATE_EVERY: Duration = Duration::from_millis(250);
const TURN: Duration = Duration::from_millis(4);

#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    Welcome,
    Ready,
    Playing,
    Ask,
    Done,
}

impl Phase {
    fn name(self) -> &'static str {
        match self {
            Phase::Welcome => "welcome",
            Phase::Ready => "ready",
            Phase::Playing => "playing",
            Phase::Ask => "ask",
            Phase::Done => "done",
        }
    }
}

/// The study served to a page.
pub struct StudyPage {
    view: FedView,
    clips: Clips,
    commands: Receiver<String>,
    out: File,
    out_path: PathBuf,
    seed: u64,
    participant: String,
    order: Vec<usize>,
    /// Position in `order` of the clip shown or asked about.
    k: usize,
    phase: Phase,
    since: Instant,
    /// Frames of the playing clip published so far.
    shown: usize,
    note: String,
    last_state: Instant,
    state_seq: u64,
    /// Participants who answered every clip, and the answers, in this session.
    pub finished: usize,
    pub answers: Vec<Answer>,
}

impl StudyPage {
    /// Serves the page at the first of `views` that can be served; answers are added to `out`
    /// (created with its header if new).
    pub fn start(clips: Clips, views: &[ViewOptions], out: &Path, seed: u64) -> anyhow::Result<StudyPage> {
        anyhow::ensure!(
            clips.clips.iter().all(|c| !c.frames.is_empty()) && !clips.clips.is_empty(),
            "no clips to show"
        );
        let out_file = open_answers(out)?;
        let (tx, commands) = sync_channel(64);
        let mut fed = Err(anyhow::anyhow!("no address to serve the page at"));
        for v in views {
            fed = FedView::start(&clips.description, v, tx.clone()).map_err(anyhow::Error::from);
            if fed.is_ok() {
                break;
            }
        }
        let fed = fed?;
        fed.publish(None, None, Some(&clips.rig), None);
        let mut s = StudyPage {
            view: fed,
            clips,
            commands,
            out: out_file,
            out_path: out.to_path_buf(),
            seed,
            participant: String::new(),
            order: Vec::new(),
            k: 0,
            phase: Phase::Welcome,
            since: Instant::now(),
            shown: 0,
            note: String::new(),
            last_state: Instant::now(),
            state_seq: 0,
            finished: 0,
            answers: Vec::new(),
        };
        s.enter(Phase::Welcome);
        Ok(s)
    }

    pub fn url(&self) -> &str {
        self.view.handle().url()
    }

    fn clip(&self) -> &crate::study::Clip {
        &self.clips.clips[self.order.get(self.k).copied().unwrap_or(0)]
    }

    fn enter(&mut self, phase: Phase) {
        self.phase = phase;
        self.since = Instant::now();
        match phase {
            // The virtual human in its guard: the clip's first frame.
            Phase::Ready | Phase::Welcome => {
                self.shown = 0;
                let first = &self.clip().frames[0];
                self.view.publish(Some(first.as_slice()), None, None, None);
            }
            _ => {}
        }
        self.publish_state();
    }

    fn publish_state(&mut self) {
        self.state_seq += 1;
        let asking = !matches!(self.phase, Phase::Welcome | Phase::Done);
        let m = json!({
            "type": "study",
            "seq": self.state_seq,
            "phase": self.phase.name(),
            "participant": self.participant,
            "index": self.k,
            "of": self.clips.clips.len(),
            "clip": if asking { Some(self.clip().id) } else { None },
            "choices": TARGETS,
            "answered": self.k.min(self.order.len()),
            "note": self.note,
        });
        self.view.publish(None, None, None, Some(m.to_string()));
        self.last_state = Instant::now();
    }

    /// Applies one message from the page; true when it changed the study.
    pub fn command(&mut self, text: &str) -> anyhow::Result<bool> {
        let Ok(c) = serde_json::from_str::<Value>(text) else { return Ok(false) };
        match (c["cmd"].as_str(), self.phase) {
            (Some("study-begin"), Phase::Welcome) => {
                let id = c["participant"].as_str().unwrap_or("").trim().to_string();
                match check_participant(&id) {
                    Ok(()) => {
                        self.order = order_for(&id, self.seed, self.clips.clips.len());
                        self.participant = id;
                        self.note.clear();
                        self.k = 0;
                        self.enter(Phase::Ready);
                    }
                    Err(why) => {
                        self.note = why;
                        self.publish_state();
                    }
                }
                Ok(true)
            }
            (Some("study-answer"), Phase::Ask) => {
                let answer = c["answer"].as_u64().map(|a| a as usize).filter(|a| *a < TARGETS.len());
                let this = c["index"].as_u64() == Some(self.k as u64)
                    && c["clip"].as_u64() == Some(self.clip().id as u64);
                let (Some(answer), true) = (answer, this) else { return Ok(false) };
                let page_s = c["response_s"].as_f64().filter(|s| s.is_finite() && *s >= 0.0);
                let response_s = page_s.unwrap_or_else(|| self.since.elapsed().as_secs_f64());
                self.record(answer, response_s)?;
                Ok(true)
            }
            _ => Ok(false),
        }
    }

    /// Writes the answer to the clip asked about and moves on.
    fn record(&mut self, answer: usize, response_s: f64) -> anyhow::Result<()> {
        let clip = self.clip();
        let a = Answer {
            participant: self.participant.clone(),
            clip: clip.id,
            active: clip.active,
            target: clip.target,
            answer,
            response_s,
        };
        writeln!(self.out, "{}", a.csv_line())
            .and_then(|_| self.out.flush())
            .with_context(|| format!("writing an answer to {}", self.out_path.display()))?;
        self.answers.push(a);
        self.k += 1;
        if self.k == self.order.len() {
            self.enter(Phase::Done);
        } else {
            self.enter(Phase::Ready);
        }
        Ok(())
    }

    /// One turn: the page's messages, the clip's frames due, the phase's end, the state.
    pub fn turn(&mut self) -> anyhow::Result<()> {
        while let Ok(c) = self.commands.try_recv() {
            self.command(&c)?;
        }
        let t = self.since.elapsed().as_secs_f64();
        match self.phase {
            Phase::Ready if t >= READY_S => self.enter(Phase::Playing),
            Phase::Playing => {
                let due = ((t / self.clips.frame_s) as usize + 1).min(self.clip().frames.len());
                if due > self.shown {
                    self.shown = due;
                    let f = &self.clips.clips[self.order[self.k]].frames[due - 1];
                    self.view.publish(Some(f.as_slice()), None, None, None);
                }
                if self.shown == self.clip().frames.len() {
                    self.enter(Phase::Ask);
                }
            }
            Phase::Done if t >= DONE_S => {
                self.finished += 1;
                self.participant.clear();
                self.order.clear();
                self.k = 0;
                self.enter(Phase::Welcome);
            }
            _ => {}
        }
        if self.last_state.elapsed() >= STATE_EVERY {
            self.publish_state();
        }
        Ok(())
    }

    /// Serves participants until `participants` have answered every clip (None: no limit) or
    /// `stop` says so.
    pub fn run(&mut self, participants: Option<usize>, stop: &dyn Fn() -> bool) -> anyhow::Result<()> {
        while !stop() && participants.is_none_or(|n| self.finished < n) {
            self.turn()?;
            std::thread::sleep(TURN);
        }
        Ok(())
    }
}

/// `spidar study reactions`' arguments.
#[derive(clap::Args, Debug)]
pub struct StudyArgs {
    /// The CSV file the answers are added to (created with its header; an existing answers file
    /// gets the new lines, so a lab can keep every participant in one file).
    #[arg(long)]
    pub out: PathBuf,
    /// Straights per target and condition: each participant sees 8 x this many clips.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u64).range(1..=100))]
    pub trials: u64,
    /// Seed of the clips (hand, speed, the virtual human) and of the participants' orders.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Stop after this many participants have answered every clip (default: until Ctrl-C).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..=10_000))]
    pub participants: Option<u64>,
    /// Serve the page at this address (HOST:PORT, :PORT or http://HOST:PORT; frames on the next
    /// port). Default http://127.0.0.1:8080, or a free port when that one is taken.
    #[arg(long, value_name = "ADDR")]
    pub view: Option<String>,
}

/// Makes the clips, serves the study until `stop` or the participants asked for, then returns
/// the confusion matrix of every answer in the file (this session's and earlier ones).
pub fn study_reactions(
    a: &StudyArgs,
    stop: &dyn Fn() -> bool,
    mut say: impl FnMut(&str),
) -> anyhow::Result<crate::study::Tally> {
    use crate::study::{make_clips, read_answers, tally, ClipOptions};
    // The file first: a bad --out is told before the clips are made.
    drop(open_answers(&a.out)?);
    let o = ClipOptions { trials: a.trials as usize, seed: a.seed, ..Default::default() };
    say(&format!(
        "making {} clips on the path of `spidar run` (simulated rig, rt-loop, boxing world, virtual clock) ...",
        8 * o.trials
    ));
    let clips = make_clips(&o, |done, total| {
        if done % 4 == 0 || done == total {
            spidar_runtime::term::progress(&format!("clips {done}/{total}"));
        }
    })?;
    spidar_runtime::term::progress_done();
    let views = match &a.view {
        Some(addr) => vec![ViewOptions { addr: spidar_world::view::parse_addr(addr)?, ..Default::default() }],
        None => vec![
            ViewOptions::default(),
            ViewOptions { addr: ([127, 0, 0, 1], 0).into(), ..Default::default() },
        ],
    };
    let mut page = StudyPage::start(clips, &views, &a.out, a.seed)?;
    say(&format!(
        "spidar study reactions: open {} (full screen: F11) and give each participant their id; answers go to {}",
        page.url(),
        a.out.display()
    ));
    page.run(a.participants.map(|n| n as usize), stop)?;
    say(&format!(
        "{} answers in this session from {} participants who finished",
        page.answers.len(),
        page.finished
    ));
    Ok(tally(&read_answers(&a.out)?))
}

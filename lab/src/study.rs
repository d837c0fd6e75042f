//! `spidar study reactions`: the boxing paper's reaction experiment (section 4.3, Table IV) run
//! with people. This module makes the clips and keeps the answers; [`crate::study_page`] serves
//! them to a page and asks.
//!
//! - The clips ([`make_clips`]) are made on the path of `spidar run`, as `spidar eval reactions`'
//!   trials are: the scripted user throws one straight (3-5 m/s, either hand) at one of Table
//!   IV's four targets of the virtual human (its left or right hand, the left or right side of
//!   its chest) through the simulated rig, the rt-loop and the boxing world on the virtual clock;
//!   the virtual human is active (its cognitive model predicts and reacts) or passive (only
//!   pushed); its own attacks are off so every motion answers the punch. A clip is the live
//!   view's frames of the virtual human from 0.3 s before the punch starts to 0.9 s after, at
//!   60 frames a second of rig time, with what would tell the target without the reaction
//!   taken out: the user's hands, strings and forces, the contacts and the flash on a part hit,
//!   the behaviour labels, and the avatar (its shapes are put far below the floor; the page does
//!   not draw it either).
//! - The answers ([`Answer`]) go to a CSV file, one line per answer as it is given; [`tally`]
//!   turns them into the confusion matrix per condition, printed next to the paper's.
//!
//! Must never: tell the page a clip's condition or target (a clip is known to the page by an id
//! that says neither), or lose an answer given (each line is written and flushed as it comes).

use std::fmt;
use std::io::Write;
use std::path::Path;

use anyhow::{bail, Context};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use spidar_msg::RigInfo;
use spidar_rt::{Clock, Rig};
use spidar_sim::boxer::BoxerParams;
use spidar_world::view::{json, FrameMaker, Layout, GLOBALS_AT, HANDS_AT, HAND_FLOATS, TENSIONS_AT};
use spidar_world::{Scene, StepView};

use crate::eval::{Confusion, TARGETS};

/// Table IV of the paper ([active, passive][target][answer]: `spidar eval reactions`' table)
/// and its total correct rates.
pub use crate::eval::PAPER;
pub const PAPER_TOTAL: [f64; 2] = [0.80, 0.33];

/// The two conditions, as the CSV names them.
pub const CONDITIONS: [&str; 2] = ["active", "passive"];

/// How the clips are made.
#[derive(Clone, Debug)]
pub struct ClipOptions {
    /// Straights per target and condition.
    pub trials: usize,
    pub seed: u64,
    /// Seconds shown before the punch starts, and after.
    pub before_s: f64,
    pub after_s: f64,
    /// Frames per second of rig time.
    pub frame_hz: f64,
}

impl Default for ClipOptions {
    fn default() -> Self {
        ClipOptions { trials: 3, seed: 0, before_s: 0.3, after_s: 0.9, frame_hz: 60.0 }
    }
}

/// One reaction to show: the view's frames (words) at `1 / frame_hz` apart.
#[derive(Clone, Debug)]
pub struct Clip {
    /// What the page and the CSV know it by (1, 2, ...; says nothing of what it shows).
    pub id: u32,
    pub active: bool,
    /// Index into [`TARGETS`].
    pub target: usize,
    pub frames: Vec<Vec<f32>>,
}

impl Clip {
    pub fn condition(&self) -> &'static str {
        CONDITIONS[usize::from(!self.active)]
    }
}

/// The clips of a study, and what the page needs to draw them.
pub struct Clips {
    /// The live view's scene description of the boxing scene.
    pub description: String,
    pub rig: RigInfo,
    pub frame_s: f64,
    pub clips: Vec<Clip>,
}

/// Makes `trials` clips per target and condition ([`make_clip`]), numbered in a shuffled order
/// (seeded), so a clip's id says nothing of its condition or target. `progress(done, total)`.
pub fn make_clips(o: &ClipOptions, mut progress: impl FnMut(usize, usize)) -> anyhow::Result<Clips> {
    let rig = Rig::default_rig();
    let scene = spidar_world::boxing::BoxingScene::new(BoxerParams::default())?;
    let look = scene.look();
    let layout = Layout::for_look(&look);
    let description = json::scene(scene.name(), &look, &layout, o.frame_hz);
    let total = 2 * TARGETS.len() * o.trials;
    let mut clips = Vec::with_capacity(total);
    for active in [true, false] {
        for target in 0..TARGETS.len() {
            for n in 0..o.trials {
                // The seeds of `spidar eval reactions`' trials.
                let s = o.seed.wrapping_mul(1_000_003) ^ ((target * 100_000 + n) as u64);
                let frames = make_clip(active, target, s, o)?;
                clips.push(Clip { id: 0, active, target, frames });
                progress(clips.len(), total);
            }
        }
    }
    clips.shuffle(&mut rand_pcg::Pcg64Mcg::seed_from_u64(o.seed ^ 0x5eed_c11b));
    for (i, c) in clips.iter_mut().enumerate() {
        c.id = i as u32 + 1;
    }
    let rig_info = spidar_rt::status::rig_info(&rig);
    Ok(Clips { description, rig: rig_info, frame_s: 1.0 / o.frame_hz, clips })
}

/// One straight at `target` on the product path (as `spidar eval reactions`' trial), and the
/// view's frames of it from `before_s` before the punch starts to `after_s` after, stripped
/// ([`strip`]).
pub fn make_clip(active: bool, target: usize, seed: u64, o: &ClipOptions) -> anyhow::Result<Vec<Vec<f32>>> {
    let (mut b, p) = crate::eval::trial_bout(active, target, seed)?;
    let look = b.scene.look();
    let avatar: Vec<usize> = look
        .shapes
        .iter()
        .enumerate()
        .filter(|(_, s)| s.name.starts_with("avatar/"))
        .map(|(k, _)| k)
        .collect();
    let mut maker = FrameMaker::new(&look);
    let layout = *maker.layout();
    let info = spidar_rt::status::rig_info(&Rig::default_rig());
    let mut buf = vec![0.0f32; layout.max_words];
    let mut frames = Vec::new();
    let frame_s = 1.0 / o.frame_hz;
    let mut next_s = p.start_s - o.before_s;
    while b.script_t_s() < p.start_s + o.after_s {
        if !b.tick().1 {
            continue;
        }
        let model = b.model(b.scene.seq()).copied().unwrap_or_default();
        let v = StepView {
            t_s: b.v.clock.now_ns() as f64 * 1e-9,
            scene: &b.scene,
            samples: &b.consumed,
            model: &model,
            rig_info: Some(&info),
            rig_status: None,
        };
        // No contacts gathered: the rig's rendered contacts would show where the fist touched.
        maker.observe(&v, false);
        if b.script_t_s() + 1e-9 >= next_s {
            maker.write(&mut buf, &v, true, true);
            frames.push(strip(&buf, &layout, &avatar));
            next_s += frame_s;
        }
    }
    Ok(frames)
}

/// A frame without what would tell the target without the reaction: the user's hands (no valid
/// hand: no grips, strings or force arrows), the string tensions, the contact forces on the
/// shapes (the flash of a part hit), the behaviour labels, the contact proxies and the contacts;
/// the avatar's shapes far below the floor.
pub fn strip(frame: &[f32], layout: &Layout, avatar: &[usize]) -> Vec<f32> {
    let mut f = frame[..layout.contacts_at].to_vec();
    f[GLOBALS_AT + 1] = 0.0;
    f[GLOBALS_AT + 2] = 0.0;
    f[GLOBALS_AT + 3] = 0.0;
    f[HANDS_AT..HANDS_AT + 2 * HAND_FLOATS].fill(0.0);
    f[TENSIONS_AT..layout.shapes_at].fill(f32::NAN);
    f[layout.shape_force_at..layout.characters_at].fill(0.0);
    f[layout.proxies_at..].fill(0.0);
    for &k in avatar {
        let at = layout.shapes_at + k * spidar_world::look::SHAPE_FLOATS;
        f[at..at + 3].copy_from_slice(&[0.0, -100.0, 0.0]);
    }
    f
}

// ---------------------------------------------------------------------------------------------
// The answers.

/// One answer, one line of the CSV file.
#[derive(Clone, Debug, PartialEq)]
pub struct Answer {
    pub participant: String,
    pub clip: u32,
    pub active: bool,
    /// Indices into [`TARGETS`].
    pub target: usize,
    pub answer: usize,
    /// From the question shown to the button pressed, as the page measured it (s).
    pub response_s: f64,
}

/// The CSV file's first line.
pub const CSV_HEADER: &str = "participant,clip,condition,target,answer,response_s";

impl Answer {
    pub fn csv_line(&self) -> String {
        format!(
            "{},{},{},{},{},{:.3}",
            self.participant,
            self.clip,
            CONDITIONS[usize::from(!self.active)],
            TARGETS[self.target],
            TARGETS[self.answer],
            self.response_s
        )
    }

    /// Reads a line written by [`Answer::csv_line`]; why not otherwise.
    pub fn parse(line: &str) -> Result<Answer, String> {
        let f: Vec<&str> = line.split(',').collect();
        let [participant, clip, condition, target, answer, response_s] = f[..] else {
            return Err(format!("{} fields, not the 6 of {CSV_HEADER}", f.len()));
        };
        let part = |name: &str, v: &str| {
            TARGETS.iter().position(|t| *t == v).ok_or(format!("{name} '{v}' is not one of {TARGETS:?}"))
        };
        Ok(Answer {
            participant: participant.to_string(),
            clip: clip.parse().map_err(|_| format!("clip '{clip}' is not a number"))?,
            active: match condition {
                "active" => true,
                "passive" => false,
                c => return Err(format!("condition '{c}' is neither active nor passive")),
            },
            target: part("target", target)?,
            answer: part("answer", answer)?,
            response_s: response_s
                .parse()
                .map_err(|_| format!("response_s '{response_s}' is not a number"))?,
        })
    }
}

/// A participant id as the CSV can hold it: 1-40 letters, digits, `.`, `_` or `-`.
pub fn check_participant(id: &str) -> Result<(), String> {
    let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-');
    if id.is_empty() || id.len() > 40 || !id.chars().all(ok) {
        return Err(format!(
            "the participant id '{id}' cannot be used: give 1 to 40 letters, digits, '.', '_' or '-'"
        ));
    }
    Ok(())
}

/// The answers file, opened to add lines: created with its header, or an existing one whose
/// first line is the header (a lab may keep all its participants in one file).
pub fn open_answers(path: &Path) -> anyhow::Result<std::fs::File> {
    let existing = std::fs::read_to_string(path).unwrap_or_default();
    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path).with_context(|| {
        format!("opening the answers file {} (give --out a file you can write)", path.display())
    })?;
    if existing.is_empty() {
        writeln!(f, "{CSV_HEADER}").with_context(|| format!("writing {}", path.display()))?;
    } else if existing.lines().next() != Some(CSV_HEADER) {
        bail!(
            "{}: line 1 is not the study's header ({CSV_HEADER}): it is not an answers file; give --out another file",
            path.display()
        );
    }
    Ok(f)
}

/// Every answer in the file, naming the file, line and field of one that does not read.
pub fn read_answers(path: &Path) -> anyhow::Result<Vec<Answer>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut lines = text.lines().enumerate();
    if lines.next().map(|(_, l)| l) != Some(CSV_HEADER) {
        bail!("{}: line 1 is not the study's header ({CSV_HEADER})", path.display());
    }
    lines
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            Answer::parse(l).map_err(|e| anyhow::anyhow!("{}: line {}: {e}", path.display(), i + 1))
        })
        .collect()
}

/// The answers as Table IV: a confusion matrix per condition.
pub struct Tally {
    pub answers: usize,
    pub participants: usize,
    /// [active, passive]
    pub conditions: [Confusion; 2],
}

pub fn tally(answers: &[Answer]) -> Tally {
    let mut conditions = [Confusion { counts: [[0; 4]; 4] }, Confusion { counts: [[0; 4]; 4] }];
    for a in answers {
        conditions[usize::from(!a.active)].counts[a.target][a.answer] += 1;
    }
    let mut people: Vec<&str> = answers.iter().map(|a| a.participant.as_str()).collect();
    people.sort_unstable();
    people.dedup();
    Tally { answers: answers.len(), participants: people.len(), conditions }
}

impl fmt::Display for Tally {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "reaction study: {} answers from {} participants", self.answers, self.participants)?;
        for (m, c) in self.conditions.iter().enumerate() {
            let n: usize = c.counts.iter().flatten().sum();
            writeln!(
                f,
                "\n{} reactions ({n} answers): rate of each answer (people here | paper)",
                CONDITIONS[m]
            )?;
            write!(f, "  {:<12}", "target")?;
            for a in TARGETS {
                write!(f, " {a:>17}")?;
            }
            writeln!(f, " {:>6}", "n")?;
            for t in 0..4 {
                write!(f, "  {:<12}", TARGETS[t])?;
                for (a, paper) in PAPER[m][t].iter().enumerate() {
                    write!(f, "      {:.2} | {:.2}", c.rate(t, a), paper)?;
                }
                writeln!(f, " {:>6}", c.counts[t].iter().sum::<usize>())?;
            }
            writeln!(f, "  total correct rate {:.2} (paper {:.2})", c.total(), PAPER_TOTAL[m])?;
        }
        write!(
            f,
            "\nthe paper: 8 people, each shown the reactions once in random order, the avatar not shown"
        )
    }
}

/// The order one participant sees the clips in: shuffled by their id and the study's seed (the
/// same id sees the same order again).
pub fn order_for(participant: &str, seed: u64, clips: usize) -> Vec<usize> {
    // FNV-1a of the id: stable across runs and builds.
    let h = participant
        .bytes()
        .fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ b as u64).wrapping_mul(0x100_0000_01b3));
    let mut order: Vec<usize> = (0..clips).collect();
    order.shuffle(&mut rand_pcg::Pcg64Mcg::seed_from_u64(h ^ seed));
    order
}

#[cfg(test)]
mod tests {
    use super::*;

    fn answer(p: &str, clip: u32, active: bool, target: usize, answer: usize) -> Answer {
        Answer { participant: p.into(), clip, active, target, answer, response_s: 0.5 + clip as f64 * 0.125 }
    }

    #[test]
    fn answers_written_as_csv_read_back_into_the_confusion_matrix_per_condition() {
        let dir = std::env::temp_dir().join(format!("spidar-study-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("answers.csv");
        let _ = std::fs::remove_file(&path);
        let given = vec![
            answer("P01", 3, true, 0, 0),
            answer("P01", 1, true, 0, 1),
            answer("P01", 7, true, 2, 2),
            answer("P01", 2, false, 1, 3),
            answer("P02", 3, true, 0, 0),
            answer("P02", 5, false, 1, 1),
            answer("P02", 6, false, 3, 0),
        ];
        // Two sessions into one file: the second adds lines under the same header.
        for part in [&given[..4], &given[4..]] {
            let mut f = open_answers(&path).unwrap();
            for a in part {
                writeln!(f, "{}", a.csv_line()).unwrap();
            }
        }
        let text = std::fs::read_to_string(&path).unwrap();
        assert_eq!(text.lines().next(), Some(CSV_HEADER));
        assert_eq!(text.lines().count(), 1 + given.len(), "one header, then a line per answer:\n{text}");
        assert_eq!(text.lines().nth(2), Some("P01,1,active,left hand,right hand,0.625"));
        let back = read_answers(&path).unwrap();
        assert_eq!(back, given);

        let t = tally(&back);
        assert_eq!((t.answers, t.participants), (7, 2));
        let [a, p] = &t.conditions;
        assert_eq!(a.counts, [[2, 1, 0, 0], [0; 4], [0, 0, 1, 0], [0; 4]]);
        assert_eq!(p.counts, [[0; 4], [0, 1, 0, 1], [0; 4], [1, 0, 0, 0]]);
        assert!((a.total() - 0.75).abs() < 1e-12 && (p.total() - 1.0 / 3.0).abs() < 1e-12);
        let s = t.to_string();
        let row = |cond: &str, target: &str| {
            let from = s.find(&format!("{cond} reactions")).unwrap();
            s[from..].lines().find(|l| l.trim_start().starts_with(target)).unwrap().to_string()
        };
        // Rates next to the paper's, and the row's count.
        let r = row("active", "left hand");
        assert!(r.contains("0.67 | 0.88") && r.contains("0.33 | 0.08") && r.trim_end().ends_with('3'), "{r}");
        let r = row("passive", "right hand");
        assert!(r.contains("0.50 | 0.42") && r.contains("0.50 | 0.08"), "{r}");
        assert!(s.contains("total correct rate 0.75 (paper 0.80)"), "{s}");
        assert!(s.contains("total correct rate 0.33 (paper 0.33)"), "{s}");
        assert!(s.contains("7 answers from 2 participants"), "{s}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_file_that_is_not_an_answers_file_is_refused_naming_file_and_line() {
        let dir = std::env::temp_dir().join(format!("spidar-study-unit-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let other = dir.join("other.csv");
        std::fs::write(&other, "a,b\n1,2\n").unwrap();
        let e = open_answers(&other).unwrap_err().to_string();
        assert!(e.contains("other.csv") && e.contains("line 1") && e.contains("--out"), "{e}");
        let bad = dir.join("bad.csv");
        std::fs::write(&bad, format!("{CSV_HEADER}\nP1,2,active,left hand,left foot,0.4\n")).unwrap();
        let e = read_answers(&bad).unwrap_err().to_string();
        assert!(e.contains("bad.csv: line 2") && e.contains("answer 'left foot'"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn participant_ids_are_checked_and_each_sees_every_clip_once_in_an_order_of_their_own() {
        assert!(check_participant("P-01.a_b").is_ok());
        for bad in ["", "a,b", "a b", "é", &"x".repeat(41)] {
            assert!(check_participant(bad).unwrap_err().contains("1 to 40"), "{bad}");
        }
        let a = order_for("P01", 7, 16);
        let mut sorted = a.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..16).collect::<Vec<_>>());
        assert_eq!(a, order_for("P01", 7, 16), "the same id sees the same order");
        assert_ne!(a, order_for("P02", 7, 16));
        assert_ne!(a, (0..16).collect::<Vec<_>>());
    }
}

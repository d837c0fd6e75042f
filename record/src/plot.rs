//! `spidar plot FILE`: one SVG of a recorded session: the force on each hand, the tension of
//! every string, the wake-up lateness histogram, and a timeline of the rig's lifecycle with the
//! hands' hits and the faults; with the world's recording (`FILE.world.mcap`, or given alone),
//! the virtual human's behaviour timeline (each hand and the body) and its hits taken and given.
//!
//! SVG through `plotters` without its font features (nothing needs fontconfig or freetype), as
//! the calibration's plots. A long session is drawn as the peak of each time bucket (at most
//! [`BUCKETS`] per series), so an hour plots as fast and as small as a minute.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;
use spidar_rt::Lifecycle;

use crate::reader::{self, Flow, Msg, Recording};
use crate::RecordError;

/// Time buckets per series, at most.
pub const BUCKETS: usize = 1500;

const HAND_COLOURS: [RGBColor; 2] = [RGBColor(31, 119, 180), RGBColor(214, 39, 40)];
const STRING_COLOURS: [[RGBColor; 4]; 2] = [
    [RGBColor(8, 48, 107), RGBColor(33, 113, 181), RGBColor(107, 174, 214), RGBColor(158, 202, 225)],
    [RGBColor(103, 0, 13), RGBColor(203, 24, 29), RGBColor(251, 106, 74), RGBColor(252, 174, 145)],
];

/// Peak of a value per time bucket; buckets double in width when there are too many.
#[derive(Clone, Debug)]
pub struct Peaks {
    t0: Option<f64>,
    width_s: f64,
    peaks: Vec<f64>,
}

impl Default for Peaks {
    fn default() -> Self {
        Peaks { t0: None, width_s: 0.001, peaks: Vec::new() }
    }
}

impl Peaks {
    pub fn add(&mut self, t_s: f64, v: f64) {
        let t0 = *self.t0.get_or_insert(t_s);
        let mut i = ((t_s - t0) / self.width_s).max(0.0) as usize;
        while i >= BUCKETS {
            self.peaks =
                self.peaks.chunks(2).map(|c| c.iter().copied().fold(f64::NEG_INFINITY, f64::max)).collect();
            self.width_s *= 2.0;
            i = ((t_s - t0) / self.width_s).max(0.0) as usize;
        }
        if self.peaks.len() <= i {
            self.peaks.resize(i + 1, f64::NEG_INFINITY);
        }
        self.peaks[i] = self.peaks[i].max(v);
    }
    /// (bucket start time, peak) of every bucket that got a value.
    pub fn points(&self) -> Vec<(f64, f64)> {
        let t0 = self.t0.unwrap_or(0.0);
        self.peaks
            .iter()
            .enumerate()
            .filter(|(_, v)| v.is_finite())
            .map(|(i, v)| (t0 + i as f64 * self.width_s, *v))
            .collect()
    }
    pub fn width_s(&self) -> f64 {
        self.width_s
    }
}

/// Lateness histogram bins: ten per decade from 1 us to 10 ms (the last holds everything later).
const LATE_BINS: usize = 41;

fn late_bin(s: f64) -> usize {
    let us = (s * 1e6).max(1.0);
    ((us.log10() * 10.0).floor() as usize).min(LATE_BINS - 1)
}

/// What the plot shows, gathered in one pass.
#[derive(Default)]
struct Data {
    force: [Peaks; 2],
    tension: [[Peaks; 4]; 2],
    late: Vec<u64>,
    /// (start, end, state) of each stretch of one lifecycle state.
    states: Vec<(f64, f64, Lifecycle)>,
    /// Contact onsets per hand (time).
    hits: [Vec<f64>; 2],
    faults: Vec<(f64, String)>,
    touching: [bool; 2],
    span: (f64, f64),
}

/// What the world's recording adds to the plot.
#[derive(Default)]
struct WorldData {
    /// (start, end, code) stretches of the left hand's, the right hand's and the body's behaviour.
    rows: [Vec<(f64, f64, u8)>; 3],
    hits_taken: Vec<f64>,
    hits_given: Vec<f64>,
    boxer_steps: u64,
    span: (f64, f64),
}

fn gather_world(path: &Path) -> Result<(Recording, WorldData), RecordError> {
    use crate::world::{decode, WorldMsg, EVENT_HIT_GIVEN, EVENT_HIT_TAKEN};
    let mut d = WorldData::default();
    let rec = reader::read(path, |_, m| {
        let Msg::Other { channel, data, .. } = m else { return Ok(Flow::Continue) };
        let msg = match decode(&channel.topic, &channel.schema, data) {
            None => return Ok(Flow::Continue),
            Some(r) => r.map_err(|e| RecordError::Corrupt {
                path: path.to_path_buf(),
                what: format!("a message on {}: {e}", channel.topic),
            })?,
        };
        match msg {
            WorldMsg::Boxer(b) => {
                let t = b.t_s;
                if d.boxer_steps == 0 {
                    d.span.0 = t;
                }
                d.boxer_steps += 1;
                d.span.1 = t;
                for (row, code) in d.rows.iter_mut().zip([b.d.hands[0], b.d.hands[1], b.d.body]) {
                    match row.last_mut() {
                        Some(s) if s.2 == code => s.1 = t,
                        _ => row.push((t, t, code)),
                    }
                }
            }
            WorldMsg::Event(e) if e.kind == EVENT_HIT_TAKEN => d.hits_taken.push(e.t_s),
            WorldMsg::Event(e) if e.kind == EVENT_HIT_GIVEN => d.hits_given.push(e.t_s),
            _ => {}
        }
        Ok(Flow::Continue)
    })?;
    Ok((rec, d))
}

/// Colours of the hands' behaviours (standby, attack, block) and the body's (standby, avoidance).
const HAND_BEHAVIOUR_COLOURS: [RGBColor; 3] =
    [RGBColor(200, 200, 200), RGBColor(255, 127, 14), RGBColor(31, 119, 180)];
const BODY_BEHAVIOUR_COLOURS: [RGBColor; 2] = [RGBColor(200, 200, 200), RGBColor(148, 103, 189)];

fn behaviour(
    area: &Area<'_>,
    w: &WorldData,
    span: (f64, f64),
    err: &impl Fn(String) -> RecordError,
) -> Result<(), RecordError> {
    let (t0, t1) = (span.0, span.1.max(span.0 + 1e-3));
    let mut c = ChartBuilder::on(area)
        .caption(
            "the virtual human: hands (grey standby, orange attack, blue block), body (grey standby, purple avoidance); hits taken (red) and given (black)",
            ("sans-serif", 14),
        )
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(80)
        .build_cartesian_2d(t0..t1, 0.0..4.0)
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("t (s)")
        .y_labels(9)
        .y_label_formatter(&|v: &f64| match (v * 2.0).round() as i32 {
            1 => "hits".into(),
            3 => "body".into(),
            5 => "right hand".into(),
            7 => "left hand".into(),
            _ => String::new(),
        })
        .disable_y_mesh()
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (r, row) in w.rows.iter().enumerate() {
        let y = 3.5 - r as f64;
        let colours: &[RGBColor] = if r < 2 { &HAND_BEHAVIOUR_COLOURS } else { &BODY_BEHAVIOUR_COLOURS };
        c.draw_series(row.iter().map(|(a, b, code)| {
            let col = colours.get(*code as usize).copied().unwrap_or(BLACK);
            Rectangle::new([(*a, y - 0.3), (b.max(*a + 1e-3), y + 0.3)], col.filled())
        }))
        .map_err(|e| err(e.to_string()))?;
    }
    for (hits, col, lo) in [(&w.hits_taken, RED, 0.5), (&w.hits_given, BLACK, 0.15)] {
        c.draw_series(
            hits.iter().map(|t| PathElement::new(vec![(*t, lo), (*t, lo + 0.35)], col.stroke_width(2))),
        )
        .map_err(|e| err(e.to_string()))?;
    }
    Ok(())
}

/// What `plot` wrote.
pub struct PlotReport {
    pub recording: Recording,
    /// The world's recording plotted with it, and the virtual human's hits taken and given.
    pub world: Option<(PathBuf, [usize; 2])>,
    pub file: PathBuf,
    pub bucket_s: f64,
    pub hits: [usize; 2],
    pub faults: usize,
}

impl std::fmt::Display for PlotReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "plot {}", self.recording.path.display())?;
        if self.recording.ticks == 0 {
            writeln!(f, "  wrote        {}", self.file.display())?;
        } else {
            writeln!(
                f,
                "  wrote        {} (force and tension: peak per {:.0} ms; {} / {} hits, {} faults)",
                self.file.display(),
                self.bucket_s * 1e3,
                self.hits[0],
                self.hits[1],
                self.faults
            )?;
        }
        if let Some((p, [taken, given])) = &self.world {
            writeln!(
                f,
                "  world        {}: behaviour timeline; hits taken {taken}, given {given}",
                p.display()
            )?;
        }
        write!(f, "  recording    {}", self.recording.ends())
    }
}

fn gather(path: &Path) -> Result<(Recording, Data), RecordError> {
    let mut d = Data { late: vec![0; LATE_BINS], ..Default::default() };
    let rec = reader::read(path, |_, m| {
        match m {
            Msg::Tick(t) => {
                let ts = t.t_s;
                if d.states.is_empty() {
                    d.span.0 = ts;
                }
                d.span.1 = ts;
                match d.states.last_mut() {
                    Some(s) if s.2 == t.state => s.1 = ts,
                    _ => d.states.push((ts, ts, t.state)),
                }
                d.late[late_bin(t.lateness_s)] += 1;
                for h in 0..2 {
                    let hr = &t.hands[h];
                    d.force[h].add(ts, hr.output_n.length());
                    for s in 0..4 {
                        d.tension[h][s].add(ts, hr.tensions_n[s]);
                    }
                    let now = hr.contacts > 0;
                    if now && !d.touching[h] {
                        d.hits[h].push(ts);
                    }
                    d.touching[h] = now;
                }
            }
            Msg::Event(e) if e.is_fault() => d.faults.push((e.t_s, e.text)),
            _ => {}
        }
        Ok(Flow::Continue)
    })?;
    Ok((rec, d))
}

type Area<'a> = DrawingArea<SVGBackend<'a>, Shift>;

fn forces(area: &Area<'_>, d: &Data, err: &impl Fn(String) -> RecordError) -> Result<(), RecordError> {
    let (t0, t1) = (d.span.0, d.span.1.max(d.span.0 + 1e-3));
    let top = d.force.iter().flat_map(|p| p.points()).map(|p| p.1).fold(0.5, f64::max) * 1.15;
    let mut c = ChartBuilder::on(area)
        .caption(
            format!(
                "force on each hand (peak per {:.0} ms); hits: dots, faults: red lines",
                d.force[0].width_s() * 1e3
            ),
            ("sans-serif", 16),
        )
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(t0..t1, 0.0..top)
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh().x_desc("t (s)").y_desc("force (N)").draw().map_err(|e| err(e.to_string()))?;
    for h in 0..2 {
        let col = HAND_COLOURS[h];
        c.draw_series(LineSeries::new(d.force[h].points(), col.stroke_width(1)))
            .map_err(|e| err(e.to_string()))?
            .label(["left hand", "right hand"][h])
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
        let y = top * (0.96 - 0.04 * h as f64);
        c.draw_series(d.hits[h].iter().map(|t| Circle::new((*t, y), 2, col.filled())))
            .map_err(|e| err(e.to_string()))?;
    }
    c.draw_series(
        d.faults.iter().map(|(t, _)| PathElement::new(vec![(*t, 0.0), (*t, top)], RED.stroke_width(1))),
    )
    .map_err(|e| err(e.to_string()))?;
    c.configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    Ok(())
}

fn tensions(area: &Area<'_>, d: &Data, err: &impl Fn(String) -> RecordError) -> Result<(), RecordError> {
    let (t0, t1) = (d.span.0, d.span.1.max(d.span.0 + 1e-3));
    let top = d.tension.iter().flatten().flat_map(|p| p.points()).map(|p| p.1).fold(1.0, f64::max) * 1.1;
    let mut c = ChartBuilder::on(area)
        .caption(
            format!("string tensions (peak per {:.0} ms)", d.tension[0][0].width_s() * 1e3),
            ("sans-serif", 16),
        )
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(50)
        .build_cartesian_2d(t0..t1, 0.0..top)
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh().x_desc("t (s)").y_desc("tension (N)").draw().map_err(|e| err(e.to_string()))?;
    for (h, colours) in STRING_COLOURS.iter().enumerate() {
        for (s, col) in colours.iter().copied().enumerate() {
            c.draw_series(LineSeries::new(d.tension[h][s].points(), col.stroke_width(1)))
                .map_err(|e| err(e.to_string()))?
                .label(format!("{} string {s}", ["left", "right"][h]))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], col.stroke_width(2)));
        }
    }
    c.configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    Ok(())
}

fn lateness(area: &Area<'_>, d: &Data, err: &impl Fn(String) -> RecordError) -> Result<(), RecordError> {
    let total: u64 = d.late.iter().sum();
    let top = d.late.iter().copied().max().unwrap_or(1).max(1) as f64 * 2.0;
    // Counts on a log scale: the rare late ticks are what matters.
    let mut c = ChartBuilder::on(area)
        .caption(
            format!("wake-up lateness of {total} ticks (ten bins per decade, log count; the last: 10 ms and later)"),
            ("sans-serif", 16),
        )
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..(LATE_BINS as f64 / 10.0), (0.5..top).log_scale())
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("lateness")
        .y_desc("ticks")
        .x_labels(5)
        .x_label_formatter(&|v: &f64| match v.round() as i32 {
            0 => "1 us".into(),
            1 => "10 us".into(),
            2 => "100 us".into(),
            3 => "1 ms".into(),
            4 => "10 ms".into(),
            _ => String::new(),
        })
        .draw()
        .map_err(|e| err(e.to_string()))?;
    c.draw_series(d.late.iter().enumerate().filter(|(_, n)| **n > 0).map(|(i, n)| {
        let x = i as f64 / 10.0;
        Rectangle::new([(x, 0.5), (x + 0.09, *n as f64)], HAND_COLOURS[0].filled())
    }))
    .map_err(|e| err(e.to_string()))?;
    Ok(())
}

fn timeline(area: &Area<'_>, d: &Data, err: &impl Fn(String) -> RecordError) -> Result<(), RecordError> {
    let (t0, t1) = (d.span.0, d.span.1.max(d.span.0 + 1e-3));
    let mut c = ChartBuilder::on(area)
        .caption(
            "timeline: rig lifecycle (grey inactive, green active, red faulted) and each hand's hits",
            ("sans-serif", 16),
        )
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(80)
        .build_cartesian_2d(t0..t1, 0.0..3.0)
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("t (s)")
        .y_labels(7)
        .y_label_formatter(&|v: &f64| match (v * 2.0).round() as i32 {
            1 => "right hits".into(),
            3 => "left hits".into(),
            5 => "rig".into(),
            _ => String::new(),
        })
        .disable_y_mesh()
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let state_col = |s: Lifecycle| match s {
        Lifecycle::Active => RGBColor(44, 160, 44),
        Lifecycle::Faulted => RGBColor(214, 39, 40),
        _ => RGBColor(180, 180, 180),
    };
    c.draw_series(
        d.states
            .iter()
            .map(|(a, b, s)| Rectangle::new([(*a, 2.2), (b.max(*a + 1e-3), 2.8)], state_col(*s).filled())),
    )
    .map_err(|e| err(e.to_string()))?;
    for (h, col) in HAND_COLOURS.iter().copied().enumerate() {
        let y = 1.5 - h as f64; // left at 1.5, right at 0.5
        c.draw_series(
            d.hits[h]
                .iter()
                .map(|t| PathElement::new(vec![(*t, y - 0.3), (*t, y + 0.3)], col.stroke_width(1))),
        )
        .map_err(|e| err(e.to_string()))?;
    }
    Ok(())
}

/// Writes the SVG of the recording at `path` to `out`.
///
/// A rig recording is plotted with its world's (`FILE.world.mcap` next to it) when there is one;
/// a world recording alone gives the behaviour timeline only.
pub fn plot(path: &Path, out: &Path) -> Result<PlotReport, RecordError> {
    let (rec, d) = gather(path)?;
    let is_world = rec.meta("role") == "world";
    let world_file = if is_world { path.to_path_buf() } else { crate::world::world_path(path) };
    let world = if is_world || world_file.exists() { Some(gather_world(&world_file)?.1) } else { None };
    let err = |m: String| RecordError::Write { path: out.to_path_buf(), why: m };
    if is_world {
        let w = world.unwrap_or_default();
        if w.boxer_steps == 0 {
            return Err(RecordError::Replay {
                path: path.to_path_buf(),
                why: "it holds no virtual human to plot (a scene without one)".into(),
            });
        }
        {
            let root = SVGBackend::new(out, (1200, 400)).into_drawing_area();
            root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
            behaviour(&root, &w, w.span, &err)?;
            root.present().map_err(|e| err(e.to_string()))?;
        }
        let hits = [w.hits_taken.len(), w.hits_given.len()];
        return Ok(PlotReport {
            recording: rec,
            file: out.to_path_buf(),
            bucket_s: 0.0,
            hits: [0, 0],
            faults: 0,
            world: Some((path.to_path_buf(), hits)),
        });
    }
    if rec.ticks == 0 {
        return Err(RecordError::Replay { path: path.to_path_buf(), why: "it holds no tick to plot".into() });
    }
    let world = world.filter(|w| w.boxer_steps > 0);
    {
        let h = if world.is_some() { 1750 } else { 1400 };
        let root = SVGBackend::new(out, (1200, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
        let (title, rest) = root.split_vertically(40);
        title
            .draw_text(
                &format!(
                    "{}: scene {}, script {}, {} ticks{}",
                    path.file_name().map_or(String::new(), |n| n.to_string_lossy().into_owned()),
                    rec.meta("scene"),
                    rec.meta("script"),
                    rec.ticks,
                    match &rec.ending {
                        Some(crate::reader::Ending::Complete) => String::new(),
                        _ => format!(
                            " (NOT COMPLETE: {}; plotted up to t = {:.3} s)",
                            match &rec.ending {
                                Some(crate::reader::Ending::Damaged { .. }) => "damaged",
                                _ => "cut short",
                            },
                            rec.last_t_s
                        ),
                    }
                ),
                &("sans-serif", 20).into_text_style(&title),
                (12, 10),
            )
            .map_err(|e| err(e.to_string()))?;
        let areas = rest.split_evenly((if world.is_some() { 5 } else { 4 }, 1));
        forces(&areas[0], &d, &err)?;
        tensions(&areas[1], &d, &err)?;
        lateness(&areas[2], &d, &err)?;
        timeline(&areas[3], &d, &err)?;
        if let Some(w) = &world {
            behaviour(&areas[4], w, d.span, &err)?;
        }
        root.present().map_err(|e| err(e.to_string()))?;
    }
    Ok(PlotReport {
        recording: rec,
        file: out.to_path_buf(),
        bucket_s: d.force[0].width_s(),
        hits: [d.hits[0].len(), d.hits[1].len()],
        faults: d.faults.len(),
        world: world.map(|w| (world_file, [w.hits_taken.len(), w.hits_given.len()])),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn peaks_keep_the_maximum_as_buckets_merge() {
        let mut p = Peaks::default();
        for i in 0..10 * BUCKETS {
            let v = if i == 7777 { 50.0 } else { (i % 10) as f64 };
            p.add(i as f64 * 0.001, v);
        }
        let pts = p.points();
        assert!(pts.len() <= BUCKETS, "{}", pts.len());
        assert_eq!(pts.iter().map(|x| x.1).fold(0.0, f64::max), 50.0);
        assert!(pts.iter().filter(|x| x.1 == 50.0).count() == 1);
        assert!((p.width_s() - 0.016).abs() < 1e-12, "{}", p.width_s());
    }

    #[test]
    fn lateness_bins_are_decades_from_one_microsecond() {
        assert_eq!(late_bin(0.0), 0);
        assert_eq!(late_bin(10e-6), 10);
        assert_eq!(late_bin(99e-6), 19);
        assert_eq!(late_bin(1e-3), 30);
        assert_eq!(late_bin(5.0), LATE_BINS - 1);
    }
}

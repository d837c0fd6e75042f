//! `spidar replay`, `spidar export` and `spidar plot`: a recording played into the live view,
//! checked bit for bit against the tick core (`--verify`), exported and plotted. The work is in
//! `spidar_record`; the replay's view in `replay_view`.

use anyhow::Context;

/// `spidar replay`.
#[derive(clap::Args)]
pub struct ReplayArgs {
    /// The recording (`spidar run --record FILE.mcap`): the rig's file or the world's
    /// (FILE.world.mcap); the other one is found next to it.
    pub file: std::path::PathBuf,
    /// Where the replay is served (the live view's page with a playback bar) and --no-view.
    #[command(flatten)]
    pub view: crate::world_process::ViewArgs,
    /// Playback speed to start with (0.0625 to 16; the page offers 0.25x to 4x).
    #[arg(long, default_value_t = 1.0, value_parser = playback_speed)]
    pub speed: f64,
    /// Start at this scene time, in seconds (default: the first frame).
    #[arg(long, value_name = "SECONDS")]
    pub from: Option<f64>,
    /// Start playing at once (default: paused on the first frame until the page says play).
    #[arg(long)]
    pub play: bool,
    /// Re-run the rt-loop's tick core from the recorded device inputs, commands and contact
    /// models, and check every output (volts, forces, tensions, lifecycle, events, hand samples)
    /// bit for bit; fails naming the first tick that differs.
    #[arg(long)]
    pub verify: bool,
    /// With --verify: build the tick core from this rig file instead of the one recorded.
    #[arg(long, requires = "verify")]
    pub rig: Option<std::path::PathBuf>,
    /// Print the summary as JSON (and serve no view).
    #[arg(long)]
    pub json: bool,
}

fn playback_speed(s: &str) -> Result<f64, String> {
    let v: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if spidar_record::play::SPEEDS.contains(&v) {
        Ok(v)
    } else {
        Err("must be between 0.0625 and 16".into())
    }
}

/// The rig's and the world's file of a recording, from either (each if it is there).
fn partners(file: &std::path::Path) -> (Option<std::path::PathBuf>, Option<std::path::PathBuf>) {
    let name = file.file_name().map_or(String::new(), |n| n.to_string_lossy().into_owned());
    match name.strip_suffix(".world.mcap") {
        Some(stem) => {
            let rig = file.with_file_name(format!("{stem}.mcap"));
            (rig.exists().then_some(rig), Some(file.to_path_buf()))
        }
        None => {
            let world = spidar_record::world::world_path(file);
            (Some(file.to_path_buf()), world.exists().then_some(world))
        }
    }
}

pub fn replay(a: &ReplayArgs) -> anyhow::Result<()> {
    if a.verify {
        let rig = match &a.rig {
            Some(p) => Some((
                p.display().to_string(),
                std::fs::read_to_string(p)
                    .with_context(|| format!("reading the rig file {}", p.display()))?,
            )),
            None => None,
        };
        let r = spidar_record::verify::verify(&a.file, rig)?;
        if a.json {
            let j = serde_json::json!({
                "command": "replay --verify",
                "file": a.file.display().to_string(),
                "rig": r.rig,
                "passed": r.passed(),
                "ticks_identical": r.ticks_identical,
                "samples_identical": r.samples_identical,
                "first_difference": r.first_difference.as_ref().map(|d| serde_json::json!({
                    "tick": d.tick, "t_s": d.t_s, "what": d.what,
                })),
                "missing_from_tick": r.gap_at,
                "ends": r.recording.ends(),
            });
            println!("{j:#}");
        } else {
            println!("{r}");
        }
        if let Some(d) = &r.first_difference {
            anyhow::bail!("the replay differs from the recording at tick {} ({})", d.tick, d.what);
        }
        if let Some(g) = r.gap_at {
            anyhow::bail!("the recording is missing ticks from tick {g} on: it cannot be verified past them");
        }
        if r.ticks_identical == 0 {
            anyhow::bail!("the recording holds no tick to verify");
        }
        return Ok(());
    }
    // Either file of a session, and the other one next to it.
    let (rig_file, world_file) = partners(&a.file);
    let serve = !(a.view.no_view || a.json);
    // The view first (opening a recording for it is quick): the summaries of an hour-long
    // recording take a while to read.
    let replay = match (&world_file, serve) {
        (Some(w), true) => Some(start_replay(w, a)?),
        (None, true) => {
            crate::errln!(
                "spidar replay: no world recording next to {} ({}): nothing to draw, the summary only",
                a.file.display(),
                spidar_record::world::world_path(&a.file).display()
            );
            None
        }
        _ => None,
    };
    let stop = crate::signals::Stop::install()?;
    let player = replay.map(|r| {
        let stop = stop.clone();
        std::thread::spawn(move || r.run(&|| stop.requested()))
    });
    let world = match &world_file {
        Some(w) => Some(spidar_record::world::summarize(w)?),
        None => None,
    };
    let rig = match &rig_file {
        Some(r) => Some(spidar_record::summary::summarize(r)?),
        None => None,
    };
    if a.json {
        let j = match &rig {
            Some(s) => {
                let mut j = s.summary().json();
                j["world"] = world.as_ref().map_or(serde_json::Value::Null, world_json);
                j
            }
            None => world.as_ref().map_or(serde_json::Value::Null, world_json),
        };
        println!("{j:#}");
    } else {
        if let Some(s) = &rig {
            println!("{s}");
        }
        if let Some(w) = &world {
            println!("{w}");
        }
    }
    if let Some(p) = player {
        crate::errln!("spidar replay: serving until Ctrl-C");
        p.join().map_err(|_| anyhow::anyhow!("the replay thread panicked"))??;
    }
    Ok(())
}

/// Starts serving a world recording into the view as `--view`, `--speed`, `--from`, `--play`
/// say, and says where on stderr.
fn start_replay(world: &std::path::Path, a: &ReplayArgs) -> anyhow::Result<crate::replay_view::Replay> {
    use spidar_world::view::{parse_addr, ViewOptions};
    let o = |view| crate::replay_view::ReplayOptions { view, from_s: a.from, speed: a.speed, play: a.play };
    let r = match &a.view.view {
        Some(addr) => crate::replay_view::Replay::start(
            world,
            &o(ViewOptions { addr: parse_addr(addr)?, ..Default::default() }),
        )?,
        // The default port may be taken (a world running): then any free one.
        None => crate::replay_view::Replay::start(world, &o(ViewOptions::default())).or_else(|_| {
            crate::replay_view::Replay::start(
                world,
                &o(ViewOptions { addr: ([127, 0, 0, 1], 0).into(), ..Default::default() }),
            )
        })?,
    };
    crate::errln!("spidar replay: {}", r.describe());
    crate::errln!("spidar replay: live view at {} (frames on {})", r.url(), r.ws_url());
    Ok(r)
}

fn world_json(w: &spidar_record::world::WorldSummary) -> serde_json::Value {
    let r = &w.recording;
    serde_json::json!({
        "file": r.path.display().to_string(),
        "session": r.session,
        "end": r.end_meta,
        "channels": r.channels.iter().map(|c| serde_json::json!({
            "topic": c.topic, "schema": c.schema, "messages": c.messages,
        })).collect::<Vec<_>>(),
        "steps": w.steps,
        "first_t_s": w.first_t_s,
        "last_t_s": w.last_t_s,
        "dropped": w.dropped,
        "events": w.events,
        "hits_taken": w.hits_taken,
        "hits_given": w.hits_given,
        "characters": w.characters,
        "complete": r.ending == Some(spidar_record::reader::Ending::Complete),
    })
}

/// `spidar export`.
#[derive(clap::Args)]
pub struct ExportArgs {
    /// The recording.
    pub file: std::path::PathBuf,
    /// Directory for the CSV files (created if missing): one per channel, e.g. rig_tick.csv.
    #[arg(long, value_name = "DIR")]
    pub csv: std::path::PathBuf,
}

pub fn export(a: &ExportArgs) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    if a.file.to_string_lossy().ends_with(".world.mcap") {
        println!("{}", spidar_record::export::export_world_csv(&a.file, &a.csv)?);
    } else {
        println!("{}", spidar_record::export::export_csv(&a.file, &a.csv)?);
        // The world's file next to it goes into the same directory (world_*.csv).
        let w = spidar_record::world::world_path(&a.file);
        if w.exists() {
            println!("{}", spidar_record::export::export_world_csv(&w, &a.csv)?);
        }
    }
    println!("  took         {:.2} s", t0.elapsed().as_secs_f64());
    Ok(())
}

/// `spidar plot`.
#[derive(clap::Args)]
pub struct PlotArgs {
    /// The recording.
    pub file: std::path::PathBuf,
    /// The SVG file to write (default: the recording's name with .svg).
    #[arg(long, short)]
    pub out: Option<std::path::PathBuf>,
}

pub fn plot(a: &PlotArgs) -> anyhow::Result<()> {
    let out = a.out.clone().unwrap_or_else(|| a.file.with_extension("svg"));
    let r = spidar_record::plot::plot(&a.file, &out)?;
    println!("{r}");
    Ok(())
}

//! `spidar bench record`: what recording costs the rig. Live sessions (`spidar run`'s path: the
//! simulated rig, the loop on its real-time thread, the scene thread, the telemetry consumer) in
//! alternating blocks with and without `--record`, so both see the same machine; the wake-up
//! lateness of each arm, and the recording's size per hour of session.

use std::path::PathBuf;
use std::time::Duration;

use spidar_rt::rt_thread::{RtOptions, RtReport};
use spidar_rt::telemetry::{DurationHist, Percentiles};
use spidar_rt::Rig;

use spidar_runtime::session::{load_scripts, run_live, sim_device, LiveOptions, SimOptions, WorldChoice};
use spidar_runtime::signals::Stop;

pub struct RecordBenchOptions {
    /// Seconds of session per arm, split into `blocks` blocks.
    pub seconds_each: f64,
    pub blocks: u32,
    pub rt: RtOptions,
    pub scene: String,
    pub script: String,
    /// Where the recordings of the benchmark go (removed afterwards).
    pub dir: PathBuf,
}

pub struct Arm {
    pub lateness: Percentiles,
    pub over_100us: u64,
    pub over_1ms: u64,
    pub ticks: u64,
}

pub struct RecordBenchReport {
    pub rt: Option<RtReport>,
    pub without: Arm,
    pub with: Arm,
    /// Bytes recorded and the rig time they cover.
    pub bytes: u64,
    pub recorded_s: f64,
    /// Tick records not kept (any cause).
    pub lost: u64,
    pub scene: String,
}

fn arm(h: &DurationHist) -> Arm {
    Arm {
        lateness: h.percentiles(),
        over_100us: h.count_above(100e-6),
        over_1ms: h.count_above(1e-3),
        ticks: h.len(),
    }
}

pub fn bench_record(rig: &Rig, o: &RecordBenchOptions) -> anyhow::Result<RecordBenchReport> {
    std::fs::create_dir_all(&o.dir)?;
    let blocks = o.blocks.max(1);
    let block_s = o.seconds_each / blocks as f64;
    let (mut without, mut with) = (DurationHist::default(), DurationHist::default());
    let (mut bytes, mut recorded_s, mut lost) = (0u64, 0.0, 0u64);
    let mut rt = None;
    for b in 0..2 * blocks {
        let recording = b % 2 == 1;
        let scripts = load_scripts(&o.script, rig, 1 + b as u64)?;
        let dev = sim_device(rig, scripts, &SimOptions::default())?;
        let scene = spidar_world::load(&o.scene)?;
        let path = o.dir.join(format!("bench-{b}.mcap"));
        let recorder = if recording {
            let info = spidar_runtime::recording::session_info(None, &o.scene, &o.script, "Sim", 1, false)?;
            Some(spidar_record::writer::RecorderThread::spawn(spidar_runtime::recording::create(
                &path, &info,
            )?)?)
        } else {
            None
        };
        let s = run_live(
            dev,
            rig,
            WorldChoice::Thread(spidar_world::host::Stepper::new(scene)),
            LiveOptions {
                seconds: Some(block_s),
                rt: o.rt.clone(),
                spin_ns: 0,
                status_every: None,
                stop: Stop::detached(),
                scene_name: o.scene.clone(),
                script_name: o.script.clone(),
                connect_timeout: Duration::from_secs(10),
                world_priority: None,
                supervisor: None,
                recorder,
            },
        )?;
        if let Some(rep) = &s.recording {
            bytes += rep.bytes;
            lost += rep.lost();
            recorded_s += s.stats.first_t_s.map_or(0.0, |t0| s.stats.last_t_s - t0);
            let _ = std::fs::remove_file(&path);
        }
        if recording { &mut with } else { &mut without }.merge(&s.stats.lateness);
        rt.get_or_insert(s.rt.clone());
        // Let the threads of the last block go before the next starts.
        std::thread::sleep(Duration::from_millis(50));
    }
    Ok(RecordBenchReport {
        rt,
        without: arm(&without),
        with: arm(&with),
        bytes,
        recorded_s,
        lost,
        scene: o.scene.clone(),
    })
}

impl std::fmt::Display for RecordBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "spidar bench record: live sessions (scene {}) alternating without and with --record",
            self.scene
        )?;
        if let Some(rt) = &self.rt {
            writeln!(f, "  real time    {rt}")?;
            for w in &rt.warnings {
                writeln!(f, "  warning      {w}")?;
            }
        }
        for (name, a) in [("without", &self.without), ("with", &self.with)] {
            writeln!(
                f,
                "  {name:<12} {} ticks: lateness {}; > 100 us {}, > 1 ms {}",
                a.ticks, a.lateness, a.over_100us, a.over_1ms
            )?;
        }
        let per_hour = if self.recorded_s > 0.0 { self.bytes as f64 / self.recorded_s * 3600.0 } else { 0.0 };
        write!(
            f,
            "  recording    {:.1} MB for {:.1} s of session: {:.2} GB per hour (extrapolated); {} records not kept",
            self.bytes as f64 / 1e6,
            self.recorded_s,
            per_hour / 1e9,
            self.lost
        )
    }
}

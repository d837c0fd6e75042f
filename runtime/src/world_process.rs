//! `spidar world`: the world process. It loads a scene, listens for a rig (a Unix socket in a
//! private directory by default, or UDP for a rig on another host), and steps the scene while a
//! rig is connected; a rig that leaves or goes silent pauses it until one connects again.
//!
//! It runs with the normal scheduler, below the rig's real-time loop, and may allocate. The first
//! line on stdout is where it listens. On stderr it says what happens on the link; with
//! `--report-status` (as the child of `spidar run`) it also writes machine-readable lines that
//! the rig shows in its status line: `@status <steps>\t<scene status>` twice a second and
//! `@report <summary>` at the end.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use spidar_link::world::{WorldLink, WorldOffer};
use spidar_link::{Endpoint, PrivateDir};
use spidar_world::host::{serve, ServeOptions, ServeReport, Stepper};
use spidar_world::{Observer, StepView};

use crate::child_world::{REPORT_PREFIX, STATUS_PREFIX};
use crate::scene_thread::setup_world_thread;
use crate::signals::Stop;

/// The world process's options (`spidar world --help`).
#[derive(clap::Args, Clone, Debug)]
pub struct WorldArgs {
    /// Scene: `boxing` (the reactive virtual human), `boxing-passive`, `crowd`, `walls` (the rig
    /// check), `spar` (two rigs box each other: two seats, docs/spar.md), or a file of any name that says what it is in its `kind`: a boxer file like
    /// configs/boxer.ron, a crowd scene like configs/scene-crowd.ron or a walls scene.
    #[arg(long, default_value = "boxing")]
    pub scene: String,
    /// The virtual human's level of skill (boxing scenes): novice, amateur or pro, each a set of
    /// perception and decision parameters of its boxer file. Default: the file's own (`skill`;
    /// the built-in file's is a good amateur).
    #[arg(long)]
    pub skill: Option<String>,
    /// Where rigs connect: unix:PATH, or udp://HOST:PORT for a rig on another host
    /// (udp://:PORT listens on 127.0.0.1 only; udp://0.0.0.0:PORT on every interface). Default:
    /// unix:$XDG_RUNTIME_DIR/spidar/world.sock, or a new private directory (printed).
    #[arg(long)]
    pub listen: Option<String>,
    /// The rig is taken as gone (and the scene paused) after this long without a datagram.
    #[arg(long, default_value_t = 0.5)]
    pub rig_lost_s: f64,
    /// Step when a virtual-clock rig's samples say a step is due, instead of on this clock
    /// (bit-identical runs through two processes; for tests).
    #[arg(long, hide = true)]
    pub lockstep: bool,
    /// Step with SCHED_FIFO at this priority: keeps the model fresh on a busy machine. Keep it
    /// below the rig's loop (80 by default). Default: the normal scheduler.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=98))]
    pub priority: Option<u8>,
    /// Write `@status` lines for a parent `spidar run` to show (set by it).
    #[arg(long, hide = true)]
    pub report_status: bool,
    /// No scene: answer every sample at once with a model carrying its times (`spidar bench
    /// link` measures the link's round trip with it).
    #[arg(long, hide = true)]
    pub echo: bool,
    #[command(flatten)]
    pub view: ViewArgs,
    /// Record the world into this MCAP file (zstd chunks): every step's body poses (Foxglove
    /// FrameTransforms and SceneUpdate, for a 3D panel), the virtual human's decisions, the
    /// crowd's control states and the world's events (hits). See docs/recording.md.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<std::path::PathBuf>,
    /// Unix time (ns) of scene time zero in the recording (set by `spidar run --record`, so the
    /// rig's file and the world's share one time line).
    #[arg(long, hide = true, requires = "record")]
    pub record_start_unix_ns: Option<u64>,
}

/// Where the live view is served (`spidar world`, and `spidar run` for its world).
#[derive(clap::Args, Clone, Debug, Default)]
pub struct ViewArgs {
    /// Serve the live 3D view at this address (HOST:PORT, :PORT or http://HOST:PORT; frames on the
    /// next port). Default http://127.0.0.1:8080, or a free port when that one is taken.
    #[arg(long, value_name = "ADDR")]
    pub view: Option<String>,
    /// No live view.
    #[arg(long, conflicts_with = "view")]
    pub no_view: bool,
    /// Serve the live view over HTTPS (and its frames over secure WebSockets) with this PEM
    /// certificate and key, as CERT.pem,KEY.pem: a headset on the network needs it (WebXR only
    /// runs in a secure context). docs/display.md says how to make and trust one.
    #[arg(long, value_name = "CERT,KEY", conflicts_with = "no_view")]
    pub view_tls: Option<String>,
    /// Serve the world's channels live to Foxglove or Lichtblick (the Foxglove WebSocket
    /// protocol) at this address, e.g. 127.0.0.1:8765 (open ws://127.0.0.1:8765 there): the same
    /// channels and messages as the world's recording. See docs/foxglove.md.
    #[arg(long, value_name = "ADDR")]
    pub foxglove: Option<String>,
}

impl ViewArgs {
    /// The same choice as arguments of a child `spidar world`.
    pub fn child_args(&self) -> Vec<std::ffi::OsString> {
        let mut args: Vec<std::ffi::OsString> = match (&self.view, self.no_view) {
            (_, true) => vec!["--no-view".into()],
            (Some(a), false) => vec!["--view".into(), a.into()],
            (None, false) => Vec::new(),
        };
        if let (Some(t), false) = (&self.view_tls, self.no_view) {
            args.extend(["--view-tls".into(), t.into()]);
        }
        if let Some(f) = &self.foxglove {
            args.extend(["--foxglove".into(), f.into()]);
        }
        args
    }
}

/// Starts the live view of `scene` as `--view`/`--no-view` say, and says where it is on stderr.
pub fn start_view(
    a: &ViewArgs,
    scene: &dyn spidar_world::Scene,
) -> anyhow::Result<Option<spidar_world::view::View>> {
    use spidar_world::view::{parse_addr, TlsIdentity, View, ViewOptions};
    if a.no_view {
        return Ok(None);
    }
    let tls = a.view_tls.as_deref().map(TlsIdentity::from_arg).transpose()?;
    let look = scene.look();
    let opts = ViewOptions { tls, world_step_s: scene.step_s(), ..Default::default() };
    let view = match &a.view {
        Some(addr) => View::start(scene.name(), &look, &ViewOptions { addr: parse_addr(addr)?, ..opts })?,
        // The default port may be taken (another spidar): then any free one.
        None => View::start(scene.name(), &look, &opts).or_else(|_| {
            View::start(
                scene.name(),
                &look,
                &ViewOptions { addr: ([127, 0, 0, 1], 0).into(), ..opts.clone() },
            )
        })?,
    };
    crate::errln!("spidar world: live view at {} (frames on {})", view.url(), view.ws_url());
    Ok(Some(view))
}

/// Starts a live Foxglove server of the world's channels at `addr` and says where on stderr.
pub fn start_foxglove(addr: &str, name: &str) -> anyhow::Result<spidar_world::foxglove::FoxgloveServer> {
    use spidar_world::foxglove::{parse_addr, FoxgloveServer};
    let channels = spidar_record::channel::foxglove_channels(&spidar_record::world::channels());
    let server = FoxgloveServer::start(parse_addr(addr)?, name, channels, Duration::from_secs(2))?;
    crate::errln!("spidar world: Foxglove live at {} (open it in Foxglove: Open connection)", server.url());
    Ok(server)
}

/// A world recording's file side and the recorder the world's observer writes through.
type WorldRecordingPair = (spidar_record::world::WorldRecording, spidar_record::world::WorldRecorder);

/// The world's live Foxglove server (`--foxglove`) and its recording (`--record`, or the live
/// server's tap alone), either absent when not asked for. Without a start time from the rig, a
/// live session (or any recording, with `stamp_now`) starts its timeline at the wall clock's now.
fn foxglove_and_recording(
    a: &WorldArgs,
    scene_arg: &str,
    label: &str,
    scene: &dyn spidar_world::Scene,
    virtual_clock: bool,
    stamp_now: bool,
) -> anyhow::Result<(Option<spidar_world::foxglove::FoxgloveServer>, Option<WorldRecordingPair>)> {
    let foxglove = match &a.view.foxglove {
        Some(addr) => Some(start_foxglove(addr, &format!("spidar world: {label}"))?),
        None => None,
    };
    let recording = match (&a.record, &foxglove) {
        (None, None) => None,
        (path, live) => Some(crate::recording::start_world_recording_with(
            path.as_deref(),
            scene_arg,
            scene,
            virtual_clock,
            a.record_start_unix_ns
                .or_else(|| (stamp_now || live.is_some()).then(|| spidar_link::sock::realtime_ns() as u64)),
            live.as_ref().map(|s| Box::new(s.publisher()) as Box<dyn spidar_record::channel::Tap>),
        )?),
    };
    Ok((foxglove, recording))
}

/// Where an echo world puts what it measured in the model it answers with: the sample's tick
/// in `seq`, its `t_s` in `stamp_s`, and the rig-to-world trip (kernel arrival time minus the
/// send time the sample carried in `ECHO_SENT_AT`) in seconds in `extra_force_n[0].x`.
pub const ECHO_MODULO_NS: i64 = 1_000_000_000_000;

/// The CLOCK_REALTIME nanoseconds (modulo `ECHO_MODULO_NS`, exact in an f64) an echo sample was
/// sent at travel in `hands[0].pos_m.x`.
pub fn echo_sample(tick: u64, t_s: f64) -> spidar_msg::HandSample {
    let mut s = spidar_msg::HandSample { tick, t_s, ..Default::default() };
    s.hands[0].pos_world_m.x = (spidar_link::sock::realtime_ns() % ECHO_MODULO_NS) as f64;
    s
}

fn run_echo(link: &mut WorldLink, stop: &Stop) {
    let (mut arrived, mut events) = (Vec::new(), Vec::new());
    while !stop.requested() {
        link.wait(Duration::from_millis(50));
        link.drain(&mut arrived, &mut events);
        events.clear();
        for a in arrived.drain(..) {
            let s = a.sample;
            let sent = s.hands[0].pos_world_m.x as i64;
            let trip = (a.arrived_ns % ECHO_MODULO_NS - sent).rem_euclid(ECHO_MODULO_NS);
            let mut m = spidar_msg::ContactModel { seq: s.tick, stamp_s: s.t_s, ..Default::default() };
            m.extra_force_n[0].x = trip as f64 * 1e-9;
            link.send_model(&m, &mut events);
        }
    }
    link.close();
}

/// Writes `@status` lines every half second.
struct StatusLines {
    last: Option<Instant>,
    steps: u64,
}

impl Observer for StatusLines {
    fn after_step(&mut self, step: &StepView<'_>) {
        self.steps += 1;
        if self.last.is_none_or(|t| t.elapsed() >= Duration::from_millis(500)) {
            self.last = Some(Instant::now());
            let _ =
                writeln!(std::io::stderr().lock(), "{STATUS_PREFIX}{}\t{}", self.steps, step.scene.status());
        }
    }
}

/// Runs the world until `stop` is requested (SIGINT, SIGTERM, SIGHUP, or the parent rig's end).
pub fn run_world(a: &WorldArgs, stop: &Stop) -> anyhow::Result<ServeReport> {
    if !(a.rig_lost_s.is_finite() && a.rig_lost_s > 0.0) {
        bail!("--rig-lost-s must be a positive number of seconds");
    }
    if a.echo {
        let listen = Endpoint::parse(a.listen.as_deref().unwrap_or(""))?;
        let offer =
            WorldOffer { scene: "echo".into(), step_s: 0.001, rig_lost_after: Duration::from_secs(3600) };
        let mut link = WorldLink::bind(&listen, offer).with_context(|| format!("listening at {listen}"))?;
        crate::outln!("spidar world: echo listening on {}", link.listening());
        let _ = std::io::stdout().flush();
        run_echo(&mut link, stop);
        return Ok(ServeReport { link: *link.stats(), ..Default::default() });
    }
    if a.scene == spidar_world::spar::NAME {
        if a.skill.is_some() {
            anyhow::bail!("--skill sets the virtual human's level; the spar scene has none (two people box each other): drop --skill");
        }
        return run_spar(a, stop);
    }
    let scene = spidar_world::load_with_skill(&a.scene, a.skill.as_deref())?;
    let step_s = scene.step_s();
    let scene_label = format!("{} ({})", a.scene, scene.name());
    // Created before the world listens: a path that cannot be written is refused before any rig
    // connects.
    let (foxglove, recording) =
        foxglove_and_recording(a, &a.scene, &scene_label, &*scene, a.lockstep, false)?;
    // The default directory lives as long as the world.
    let (listen, _dir) = listen_endpoint(a)?;
    let offer =
        WorldOffer { scene: a.scene.clone(), step_s, rig_lost_after: Duration::from_secs_f64(a.rig_lost_s) };
    let mut link = WorldLink::bind(&listen, offer).with_context(|| format!("listening at {listen}"))?;
    let at = link.listening().clone();
    if let Some(p) = a.priority {
        let rep = setup_world_thread(Some(p));
        for w in &rep.warnings {
            crate::errln!("spidar world: warning: {w}");
        }
    }
    crate::outln!("spidar world: scene {scene_label} listening on {at}");
    let _ = std::io::stdout().flush();
    if !a.report_status {
        crate::errln!("spidar world: connect a rig with `spidar run --world {at}`; waiting for a rig");
    }
    let view = start_view(&a.view, &*scene)?;
    let mut stepper = Stepper::new(scene);
    if let Some(v) = view {
        stepper.add_observer(Box::new(v));
    }
    if a.report_status {
        stepper.add_observer(Box::new(StatusLines { last: None, steps: 0 }));
    }
    let recording = recording.map(|(rec, observer)| {
        stepper.add_observer(Box::new(observer));
        rec
    });
    let stop_fn = || stop.requested();
    let rep = serve(&mut stepper, &mut link, &ServeOptions { lockstep: a.lockstep }, &stop_fn, &mut |line| {
        crate::errln!("spidar world: {line}")
    });
    if let Some(r) = recording {
        let rep = r.finish();
        if a.record.is_some() {
            crate::errln!("spidar world: recording {rep}");
        }
    }
    if let Some(f) = foxglove {
        stop_foxglove(f);
    }
    if a.report_status {
        crate::errln!("{STATUS_PREFIX}{}\t{}", rep.steps, stepper.scene().status());
        crate::errln!("{REPORT_PREFIX}{rep}");
    } else {
        crate::errln!("spidar world: {rep}");
        let status = stepper.scene().status();
        if !status.is_empty() {
            crate::errln!("spidar world: {status}");
        }
    }
    Ok(rep)
}

/// Stops a live Foxglove server and says what it served.
fn stop_foxglove(mut f: spidar_world::foxglove::FoxgloveServer) {
    f.stop();
    let c = f.counters();
    let g = |x: &std::sync::atomic::AtomicU64| x.load(std::sync::atomic::Ordering::Relaxed);
    crate::errln!(
        "spidar world: Foxglove: {} clients ({} dropped for not reading), {} messages sent, {} dropped",
        g(&c.clients_total),
        g(&c.clients_dropped),
        g(&c.messages_sent),
        g(&c.messages_dropped)
    );
}

/// `spidar world --scene spar`: two seats, one rig each (docs/spar.md), with the live view of
/// both bodies, the world's recording (`--record`) and its channels live to Foxglove
/// (`--foxglove`, the recording's channels); each rig records its own channels with `spidar run
/// --record`.
fn run_spar(a: &WorldArgs, stop: &Stop) -> anyhow::Result<ServeReport> {
    use spidar_world::spar::{serve_spar, SparScene, NAME};
    if a.lockstep {
        bail!(
            "--scene spar has no --lockstep: its two rigs run on their own clocks; leave --lockstep out of \
             `spidar world` (the spar bouts on one virtual clock are `spidar bench spar`)"
        );
    }
    let mut scene = SparScene::new(spidar_sim::boxer::BoxerParams::default())?;
    // Created before the world listens: a port or a path that cannot be used is refused first.
    let (foxglove, recording) =
        foxglove_and_recording(a, NAME, &format!("{NAME} (two seats)"), &scene, false, true)?;
    let (listen, _dir) = listen_endpoint(a)?;
    let offer = WorldOffer {
        scene: NAME.into(),
        step_s: spidar_world::Scene::step_s(&scene),
        rig_lost_after: Duration::from_secs_f64(a.rig_lost_s),
    };
    let mut link = WorldLink::bind_seats(&listen, offer, spidar_sim::boxer::spar::SEATS)
        .with_context(|| format!("listening at {listen}"))?;
    let at = link.listening().clone();
    if let Some(p) = a.priority {
        for w in &setup_world_thread(Some(p)).warnings {
            crate::errln!("spidar world: warning: {w}");
        }
    }
    crate::outln!("spidar world: scene spar (two seats) listening on {at}");
    let _ = std::io::stdout().flush();
    crate::errln!(
        "spidar world: connect two rigs, each with `spidar run --world {at}` (the first takes seat 0, the avatar; \
         the second seat 1, in front of it); waiting for rigs"
    );
    let mut observers: Vec<Box<dyn Observer>> = Vec::new();
    if let Some(v) = start_view(&a.view, &scene)? {
        crate::errln!("spidar world: the view shows seat 1's eye with ?seat=1 (camera: eye)");
        observers.push(Box::new(v));
    }
    let recording = recording.map(|(rec, observer)| {
        observers.push(Box::new(observer));
        rec
    });
    let stop_fn = || stop.requested();
    let rep = serve_spar(&mut scene, &mut link, &mut observers, &stop_fn, &mut |line| {
        crate::errln!("spidar world: {line}")
    });
    drop(observers);
    if let Some(r) = recording {
        let rep = r.finish();
        if a.record.is_some() {
            crate::errln!("spidar world: recording {rep}");
        }
    }
    if let Some(f) = foxglove {
        stop_foxglove(f);
    }
    crate::errln!("spidar world: {rep}");
    crate::errln!("spidar world: {}", scene.status());
    Ok(rep)
}

/// Where a world listens: `--listen`, or `world.sock` in a private directory made for it (the
/// caller keeps the directory alive as long as the world serves).
fn listen_endpoint(a: &WorldArgs) -> anyhow::Result<(Endpoint, Option<PrivateDir>)> {
    Ok(match &a.listen {
        Some(s) => (Endpoint::parse(s)?, None),
        None => {
            let d =
                PrivateDir::user_default().context("making a private directory for the world's socket")?;
            (Endpoint::unix(&d.join("world.sock")), Some(d))
        }
    })
}

//! What `run --record` writes about the session: the rig file, scene and script files that made
//! it, the world's recording, and how the session ended. The work is in `spidar_record`.

use std::path::Path;

use anyhow::Context;
use spidar_record::world::{WorldInfo, WorldRecorder, WorldRecording};
use spidar_record::writer::{EndInfo, Recorder, SessionInfo};
use spidar_rt::rig::{DEFAULT_RIG_NAME, DEFAULT_RIG_RON};

use crate::summary::SessionSummary;

/// What made a session, from its arguments: the rig file's text, the scene and script files.
pub fn session_info(
    rig_path: Option<&Path>,
    scene: &str,
    script: &str,
    device: &str,
    seed: u64,
    virtual_clock: bool,
) -> anyhow::Result<SessionInfo> {
    let (rig_origin, rig_text) = match rig_path {
        Some(p) => (
            p.display().to_string(),
            std::fs::read_to_string(p).with_context(|| format!("reading the rig file {}", p.display()))?,
        ),
        None => (DEFAULT_RIG_NAME.to_string(), DEFAULT_RIG_RON.to_string()),
    };
    let mut files = Vec::new();
    for f in [scene, script] {
        if f.ends_with(".ron") {
            let text = std::fs::read_to_string(f).with_context(|| format!("reading {f}"))?;
            let name = Path::new(f).file_name().map_or(f.to_string(), |n| n.to_string_lossy().into_owned());
            files.push((name, text));
        }
    }
    Ok(SessionInfo {
        rig_origin,
        rig_text,
        scene: scene.into(),
        script: script.into(),
        device: device.into(),
        seed,
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
        virtual_clock,
        files,
    })
}

/// Creates the recording before anything starts, so a path that cannot be written is refused
/// before the rig moves.
pub fn create(path: &Path, info: &SessionInfo) -> anyhow::Result<Recorder> {
    Ok(Recorder::create(path, info)?)
}

/// Starts the world's recording of `scene` (asked as `scene_arg`) into `path`: the file is
/// created here (an unwritable path fails before the session starts). Returns the recording (to
/// finish when the world stops) and the observer to add to the scene's host.
pub fn start_world_recording(
    path: &Path,
    scene_arg: &str,
    scene: &dyn spidar_world::Scene,
    virtual_clock: bool,
    start_unix_ns: Option<u64>,
) -> anyhow::Result<(WorldRecording, WorldRecorder)> {
    start_world_recording_with(Some(path), scene_arg, scene, virtual_clock, start_unix_ns, None)
}

/// The world's recording into `path` (None: no file) and/or to a live Foxglove server `tap`:
/// the same channels and messages either way.
pub fn start_world_recording_with(
    path: Option<&Path>,
    scene_arg: &str,
    scene: &dyn spidar_world::Scene,
    virtual_clock: bool,
    start_unix_ns: Option<u64>,
    tap: Option<Box<dyn spidar_record::channel::Tap>>,
) -> anyhow::Result<(WorldRecording, WorldRecorder)> {
    let mut files = Vec::new();
    if scene_arg.ends_with(".ron") {
        let text = std::fs::read_to_string(scene_arg).with_context(|| format!("reading {scene_arg}"))?;
        let name = Path::new(scene_arg)
            .file_name()
            .map_or(scene_arg.to_string(), |n| n.to_string_lossy().into_owned());
        files.push((name, text));
    }
    let info = WorldInfo {
        scene: format!("{scene_arg} ({})", scene.name()),
        name: scene.name().into(),
        command_line: std::env::args().collect::<Vec<_>>().join(" "),
        clock: if virtual_clock { "virtual" } else { "real" }.into(),
        start_unix_ns,
        files,
    };
    Ok(WorldRecording::start_with(path, &info, &scene.look(), tap)?)
}

/// How a live session ended, for the recording's `spidar.end` record.
pub fn end_info(s: &SessionSummary) -> EndInfo {
    EndInfo {
        ticks: s.counters.ticks,
        telemetry_dropped: s.counters.telemetry_dropped,
        final_state: s.final_state.name().into(),
        clean_stop: s.clean_stop,
        faults: s.counters.faults,
    }
}

/// The rig's recorder thread of a live session: the file `rec` (if any) and, with `foxglove`
/// (the world's `--foxglove` address), a live Foxglove server of the rig's channels on the port
/// after it (any free port when it is 0); also the server's address.
pub fn recorder_thread(
    rec: Option<spidar_record::writer::Recorder>,
    foxglove: Option<&str>,
) -> anyhow::Result<(Option<spidar_record::writer::RecorderThread>, Option<String>)> {
    use spidar_record::writer::{LiveRig, RecorderThread};
    use spidar_world::foxglove::{parse_addr, FoxgloveServer};
    let mut url = None;
    let live = match foxglove {
        Some(addr) => {
            let mut at = parse_addr(addr)?;
            if at.port() != 0 {
                at.set_port(at.port().checked_add(1).context("--foxglove: no port after the world's")?);
            }
            let channels = spidar_record::channel::foxglove_channels(&spidar_record::writer::rig_channels());
            let server = FoxgloveServer::start(
                at,
                "spidar run: the rig",
                channels,
                std::time::Duration::from_secs(2),
            )?;
            crate::errln!(
                "spidar: the rig's channels live to Foxglove at {} (the world's at {addr})",
                server.url()
            );
            url = Some(server.url());
            let start =
                rec.as_ref().map_or_else(|| spidar_link::sock::realtime_ns() as u64, |r| r.start_unix_ns());
            // The recorder thread owns the server: it stops when the session's recording ends.
            Some(LiveRig::new(start, Box::new(server)))
        }
        None => None,
    };
    if rec.is_none() && live.is_none() {
        return Ok((None, url));
    }
    Ok((Some(RecorderThread::spawn_with(rec, live)?), url))
}

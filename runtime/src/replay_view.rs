//! `spidar replay`'s view: a world recording played into the live view's page, with the page's
//! playback bar (play, pause, seek, speed) driving it. The page and its server are the live
//! view's ([`spidar_world::view::FedView`]); the frames, the heads-up display's numbers and the
//! rig's geometry are the ones the world recorded as it drew them live
//! ([`spidar_record::play`]).
//!
//! The page sends small JSON commands over its WebSocket: `{"cmd":"play"}`, `{"cmd":"pause"}`,
//! `{"cmd":"seek","t_s":12.5}`, `{"cmd":"speed","x":2}`. The replay answers with a `playback`
//! message (position, range, playing, speed, how the file ends) whenever something changed and
//! four times a second.
//!
//! The screen: the world recording keeps the rig's geometry but not its `display` section; the
//! rig file the session ran with is attached to the rig's recording next to it (`rig.ron`), and
//! its screen (in the world frame, as the live world had it) is given to every frame's rig
//! geometry, so a replay draws the user's-eye view through the same screen, mono or stereo, as
//! the live page did. Without the rig's recording (or a screen in its rig file) the replay draws
//! the user's eye without one.

use std::path::Path;
use std::sync::mpsc::{sync_channel, Receiver};
use std::time::{Duration, Instant};

use serde_json::{json, Value};
use spidar_record::play::{Indexed, Player, ViewTrack};
use spidar_record::reader::Ending;
use spidar_world::view::{FedView, ViewHandle, ViewOptions};

/// How often the playback message goes out when nothing changed.
const PLAYBACK_EVERY: Duration = Duration::from_millis(250);
/// How often the replay looks at the clock and its commands.
const TURN: Duration = Duration::from_millis(4);

/// How a replay starts.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    pub view: ViewOptions,
    /// Scene time to start at (default: the first frame).
    pub from_s: Option<f64>,
    pub speed: f64,
    /// Play at once (otherwise paused until the page says play).
    pub play: bool,
}

/// A world recording served into the view.
pub struct Replay {
    view: FedView,
    player: Player,
    commands: Receiver<String>,
    last: Instant,
    last_playback: Instant,
    /// Wall seconds played (the replay's own clock: position = start + speed x this).
    clock_s: f64,
    /// Commands applied so far (a page knows its command was taken).
    applied: u64,
    ends: String,
    file: String,
    /// The screen of the rig file the session ran with (world frame), if it had one.
    display: Option<spidar_msg::DisplayInfo>,
}

/// The screen of the rig file attached to the rig's recording next to `world_file` (its stem's
/// `.mcap`), in the world frame as the session's world had it; None without one (no such file,
/// no rig file attached, or no `display` section). A rig file that does not load says so.
pub fn recorded_screen(world_file: &Path) -> Option<spidar_msg::DisplayInfo> {
    let name = world_file.file_name()?.to_string_lossy().into_owned();
    let rig_file = world_file.with_file_name(format!("{}.mcap", name.strip_suffix(".world.mcap")?));
    // The attachments come first in the file: read up to the first message.
    let rec = spidar_record::reader::read(&rig_file, |_, _| Ok(spidar_record::reader::Flow::Stop)).ok()?;
    let text = rec.rig_text()?;
    match spidar_rt::Rig::from_str(&text, &format!("rig.ron attached to {}", rig_file.display())) {
        Ok(rig) => rig.display.is_some().then(|| spidar_rt::status::rig_info(&rig).display),
        Err(e) => {
            crate::errln!("spidar replay: the screen is not drawn: {e}");
            None
        }
    }
}

impl Replay {
    /// Opens the world recording, indexes it and starts serving the page.
    pub fn start(world_file: &Path, o: &ReplayOptions) -> anyhow::Result<Replay> {
        let track = ViewTrack::open(world_file)?;
        let ends = match &track.ending {
            Ending::Complete => "complete".to_string(),
            Ending::CutShort { at_byte } => format!(
                "cut short at byte {at_byte} (the session was killed or the disk filled up): it plays up to t = {:.3} s",
                track.last_t_s
            ),
            Ending::Damaged { at_byte, why } => {
                format!("damaged from byte {at_byte} ({why}): it plays up to t = {:.3} s", track.last_t_s)
            }
        };
        let (tx, commands) = sync_channel(64);
        let view = FedView::start(&track.description, &o.view, tx)?;
        let file = world_file.file_name().map_or(String::new(), |n| n.to_string_lossy().into_owned());
        let mut player = Player::new(track)?;
        player.set_speed(o.speed);
        if let Some(t) = o.from_s {
            player.seek(t)?;
        }
        player.play(o.play)?;
        let mut r = Replay {
            view,
            player,
            commands,
            last: Instant::now(),
            last_playback: Instant::now(),
            clock_s: 0.0,
            applied: 0,
            ends,
            file,
            display: recorded_screen(world_file),
        };
        r.publish_frame();
        r.publish_playback();
        Ok(r)
    }

    pub fn url(&self) -> &str {
        self.view.handle().url()
    }

    pub fn ws_url(&self) -> &str {
        self.view.handle().ws_url()
    }

    pub fn handle(&self) -> ViewHandle {
        self.view.handle().clone()
    }

    pub fn player(&self) -> &Player {
        &self.player
    }

    /// How the track was indexed and how the file ends, in words.
    pub fn describe(&self) -> String {
        let t = self.player.track();
        format!(
            "{}: frames from t = {:.3} s to {:.3} s, {} chunks indexed from {}; {}",
            t.path.display(),
            t.first_t_s,
            t.last_t_s,
            t.chunks(),
            match t.indexed {
                Indexed::Summary => "its summary",
                Indexed::ChunkHeaders => "its chunks' headers (no summary)",
            },
            self.ends
        )
    }

    fn publish_frame(&mut self) {
        let f = self.player.frame();
        let (status, mut info) = (f.status(), f.rig_info());
        if let (Some(i), Some(d)) = (info.as_mut(), self.display) {
            if !i.display.present {
                i.display = d;
            }
        }
        self.view.publish(Some(&f.frame), Some(&status), info.as_ref(), None);
    }

    fn publish_playback(&mut self) {
        let p = &self.player;
        let t = p.track();
        let m = json!({
            "type": "playback",
            "file": self.file,
            "t_s": p.t_s(),
            "frame_t_s": p.frame().t_s,
            "first_s": t.first_t_s,
            "last_s": t.last_t_s,
            "playing": p.playing(),
            "speed": p.speed(),
            "at_end": p.at_end(),
            "clock_s": self.clock_s,
            "commands": self.applied,
            "complete": t.ending == Ending::Complete,
            "ends": self.ends,
        });
        self.view.publish(None, None, None, Some(m.to_string()));
        self.last_playback = Instant::now();
    }

    /// Applies one command (as a page sends it); false when it is not one.
    pub fn command(&mut self, text: &str) -> anyhow::Result<bool> {
        let Ok(c) = serde_json::from_str::<Value>(text) else { return Ok(false) };
        match c["cmd"].as_str() {
            Some("play") => self.player.play(true)?,
            Some("pause") => self.player.play(false)?,
            Some("seek") => match c["t_s"].as_f64() {
                Some(t) => {
                    self.player.seek(t)?;
                    self.publish_frame();
                }
                None => return Ok(false),
            },
            Some("speed") => match c["x"].as_f64() {
                Some(x) => self.player.set_speed(x),
                None => return Ok(false),
            },
            _ => return Ok(false),
        }
        self.applied += 1;
        Ok(true)
    }

    /// One turn: the commands that came, the time gone by, the frame due, the playback state.
    pub fn turn(&mut self) -> anyhow::Result<()> {
        let mut changed = false;
        while let Ok(c) = self.commands.try_recv() {
            changed |= self.command(&c)?;
        }
        let now = Instant::now();
        let dt = now.duration_since(self.last).as_secs_f64();
        self.last = now;
        let was_playing = self.player.playing();
        if was_playing {
            self.clock_s += dt;
        }
        if self.player.advance(dt)?.is_some() {
            self.publish_frame();
        }
        changed |= was_playing != self.player.playing();
        if changed || self.last_playback.elapsed() >= PLAYBACK_EVERY {
            self.publish_playback();
        }
        Ok(())
    }

    /// Plays until `stop` says so.
    pub fn run(mut self, stop: &dyn Fn() -> bool) -> anyhow::Result<()> {
        while !stop() {
            self.turn()?;
            std::thread::sleep(TURN);
        }
        Ok(())
    }
}

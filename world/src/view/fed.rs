//! A view fed frame by frame by its host instead of by a world's steps: `spidar replay` serves a
//! recording with it. The same page, server, threads and messages as the live view; the page's
//! text messages (the playback controls) are handed to the host.

use std::sync::atomic::Ordering;
use std::sync::mpsc::SyncSender;
use std::sync::Arc;
use std::time::Duration;

use glam::DVec3;
use serde_json::Value;
use spidar_msg::RigInfo;

use super::{frame_buffers, server, FrameFinisher, FrameWriterEnds, Shared, StatusData, ViewError};
use super::{ViewHandle, ViewOptions};

/// A view whose frames, status and rig geometry its host publishes.
pub struct FedView {
    shared: Arc<Shared>,
    server: Option<server::Server>,
    handle: ViewHandle,
    frames: FrameWriterEnds,
}

impl FedView {
    /// Serves the page for the scene `description` (the live view's `scene` message, as a world
    /// recording keeps it). The viewers' text messages go to `commands` (dropped when it is full).
    pub fn start(
        description: &str,
        opts: &ViewOptions,
        commands: SyncSender<String>,
    ) -> Result<FedView, ViewError> {
        let bad = |why: &str| ViewError::Description(why.to_string());
        let d: Value = serde_json::from_str(description).map_err(|e| bad(&e.to_string()))?;
        if d["type"] != "scene" {
            return Err(bad("it is not a scene description"));
        }
        let counters: Vec<String> = d["counters"]
            .as_array()
            .ok_or_else(|| bad("it has no counters"))?
            .iter()
            .map(|c| c.as_str().unwrap_or("?").to_string())
            .collect();
        let o = &d["link_offset_m"];
        let f = |i: usize| o[i].as_f64().ok_or_else(|| bad("it has no link_offset_m"));
        let offset = DVec3::new(f(0)?, f(1)?, f(2)?);
        let shared = Shared::new(Some(commands));
        // Recorded frames are whole: nothing to finish.
        let (frames, sender) = frame_buffers(0, 0);
        let finisher = FrameFinisher::new(&crate::look::Look::default());
        let scene = server::Scene {
            description: description.to_string(),
            counter_names: counters,
            offset,
            frames: sender,
            finisher,
        };
        let server = server::Server::start(opts, shared.clone(), scene)?;
        let urls = (format!("http://{}", server.http_addr), format!("ws://{}", server.ws_addr));
        let handle = ViewHandle { shared: shared.clone(), urls };
        Ok(FedView { shared, server: Some(server), handle, frames })
    }

    /// Hands the viewers a frame (the live view's binary frame, as words), a status, the rig's
    /// geometry (sent when it changes) and the playback state (JSON), whichever are given.
    pub fn publish(
        &self,
        frame: Option<&[f32]>,
        status: Option<&StatusData>,
        rig: Option<&RigInfo>,
        playback: Option<String>,
    ) {
        if let Some(f) = frame {
            // The broadcaster hands buffers back as soon as it has sent them; a replay may wait.
            let b = self.frames.take(&self.shared.counters);
            match b.or_else(|| self.frames.free.recv_timeout(Duration::from_secs(1)).ok()) {
                Some(mut b) => {
                    b.words.clear();
                    b.words.extend_from_slice(f);
                    b.len = f.len();
                    b.figures_pending = false;
                    if self.frames.full.try_send(b).is_ok() {
                        self.shared.counters.frames_published.fetch_add(1, Ordering::Relaxed);
                    }
                }
                None => {
                    self.shared.counters.frames_skipped.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        let Ok(mut mb) = self.shared.mailbox.lock() else { return };
        if let Some(s) = status {
            mb.status = *s;
            mb.status_fresh = true;
        }
        if let Some(r) = rig {
            if mb.rig != Some(*r) {
                mb.rig = Some(*r);
                mb.rig_fresh = true;
            }
        }
        if playback.is_some() {
            mb.playback = playback;
        }
        drop(mb);
        self.shared.fresh.store(true, Ordering::Release);
    }

    /// Its addresses and counters.
    pub fn handle(&self) -> &ViewHandle {
        &self.handle
    }
}

impl Drop for FedView {
    fn drop(&mut self) {
        self.shared.stop(self.server.take());
    }
}

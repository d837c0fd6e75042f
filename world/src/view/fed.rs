//! A view fed frame by frame by its host instead of by a world's steps: `spidar replay` serves a
//! recording with it. The same page, server, threads and messages as the live view; the page's
//! text messages (the playback controls) are handed to the host.

use std::sync::atomic::Ordering;
use std::sync::mpsc::SyncSender;
use std::sync::Arc;

use glam::DVec3;
use serde_json::Value;
use spidar_msg::RigInfo;

use super::{server, Shared, StatusData, ViewError, ViewHandle, ViewOptions};

/// A view whose frames, status and rig geometry its host publishes.
pub struct FedView {
    shared: Arc<Shared>,
    server: Option<server::Server>,
    handle: ViewHandle,
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
        let shared = Shared::new(0, Some(commands));
        let server = server::Server::start(opts, shared.clone(), description.to_string(), counters, offset)?;
        let urls = (format!("http://{}", server.http_addr), format!("ws://{}", server.ws_addr));
        let handle = ViewHandle { shared: shared.clone(), urls };
        Ok(FedView { shared, server: Some(server), handle })
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
        let Ok(mut mb) = self.shared.mailbox.lock() else { return };
        if let Some(f) = frame {
            mb.frame.clear();
            mb.frame.extend_from_slice(f);
            mb.frame_words = f.len();
            mb.frame_fresh = true;
            self.shared.counters.frames_published.fetch_add(1, Ordering::Relaxed);
        }
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

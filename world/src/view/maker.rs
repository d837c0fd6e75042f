//! Turning the world's steps into the view's frames and status. The live view ([`super::View`])
//! makes its frames with a [`FrameMaker`], and so does a world recording (`spidar-record`), which
//! keeps them for `spidar replay` to send the page exactly what it drew live.
//!
//! A frame is made in two parts. On the stepping thread, [`FrameMaker::write`] writes everything
//! but a crowd's drawn figures, and the scene copies the figures' states
//! ([`crate::Scene::figure_states`]); on a thread of the view's (or the recorder's), a
//! [`FrameFinisher`] computes the figures from those states and writes their joints: the frame
//! the scene would have written at that step with its figures (`figures_now`), bit for bit.
//!
//! Must never: allocate, block or format in [`FrameMaker`] (it runs on the world's stepping
//! thread).

use std::sync::Arc;

use glam::DVec3;
use spidar_msg::{ContactModel, HandState, ProxyId, HANDS, MAX_PROXIES};
use spidar_sim::character::drawn::{FigureState, Figures};
use spidar_sim::character::skeleton::MAX_JOINTS;
use spidar_sim::impulse::{nearest_on_surface, touching_hand};

use super::frame::{self, Layout};
use super::json::StatusData;
use crate::look::{put_joints, DrawnContact, Look};
use crate::StepView;

/// A rendered contact gathered between two frames.
#[derive(Clone, Copy, Default)]
struct Rendered {
    id: ProxyId,
    contact: DrawnContact,
}

/// Contact models remembered, so the impulses of late samples find their proxies.
const KEPT_MODELS: usize = 8;

/// What the view draws of a world, kept up to date step by step: the newest hands, the rig's
/// status, the contacts the rig rendered since the last frame; and the frame itself on demand.
pub struct FrameMaker {
    layout: Layout,
    offset: DVec3,
    /// Proxy id of each look shape, and whether proxy bodies are crowd characters.
    shape_proxies: Vec<Option<ProxyId>>,
    proxies_are_characters: bool,
    seq: u32,
    models: [ContactModel; KEPT_MODELS],
    rendered: [Rendered; MAX_PROXIES],
    rendered_count: usize,
    hands: [HandState; HANDS],
    /// The newest hand sample's rig tick and loop-clock time.
    tick: u64,
    tick_t_s: f64,
    /// Stamp frames with the wall-clock time of their tick (the live view: the page measures the
    /// picture's age by it); off for recordings, whose frames must not depend on when they ran.
    wall_clock: bool,
    status: StatusData,
    rate_window: (f64, u64),
}

impl FrameMaker {
    pub fn new(look: &Look) -> FrameMaker {
        FrameMaker {
            layout: Layout::for_look(look),
            offset: look.link_offset_m,
            shape_proxies: look.shapes.iter().map(|s| s.proxy).collect(),
            proxies_are_characters: look.crowd.as_ref().is_some_and(|c| c.proxy_body_is_character),
            seq: 0,
            models: [ContactModel::default(); KEPT_MODELS],
            rendered: [Rendered::default(); MAX_PROXIES],
            rendered_count: 0,
            hands: [HandState::default(); HANDS],
            tick: 0,
            tick_t_s: f64::NAN,
            wall_clock: false,
            status: StatusData { sample_t_s: f64::NAN, ..Default::default() },
            rate_window: (f64::NAN, 0),
        }
    }

    /// Stamps the frames with their tick's wall-clock time ([`frame::Common::tick_wall_ms`]).
    pub fn with_wall_clock(mut self) -> FrameMaker {
        self.wall_clock = true;
        self
    }

    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// The status as of the last step observed (its counters as of the last frame written).
    pub fn status(&self) -> &StatusData {
        &self.status
    }

    /// Takes in one step: the newest hands, the rig's status, the step count and rate; with
    /// `contacts` (someone will see the next frame), also the contact model and the contacts the
    /// rig rendered in the step's samples, kept for the next frame.
    pub fn observe(&mut self, step: &StepView<'_>, contacts: bool) {
        let t = step.t_s;
        if contacts {
            // The models the rendered contacts of the coming samples refer to.
            let k = (step.model.seq as usize) % KEPT_MODELS;
            self.models[k] = *step.model;
        }
        if let Some(s) = step.samples.last() {
            self.hands = s.hands;
            self.tick = s.tick;
            self.tick_t_s = s.t_s;
            self.status.sample_t_s = t;
        }
        self.status.t_s = t;
        self.status.steps += 1;
        if self.rate_window.0.is_nan() {
            self.rate_window = (t, self.status.steps);
        } else if t - self.rate_window.0 >= 0.5 {
            self.status.step_rate_hz =
                (self.status.steps - self.rate_window.1) as f64 / (t - self.rate_window.0);
            self.rate_window = (t, self.status.steps);
        }
        if let Some(r) = step.rig_status {
            if self.status.rig.is_none_or(|o| o.tick != r.tick) {
                self.status.rig_seen_t_s = t;
            }
            self.status.rig = Some(*r);
        }
        if contacts {
            self.gather_rendered(step);
        }
    }

    /// Gathers the contacts the rig rendered in this step's samples (the virtual contact's own
    /// force, on the body the proxy stands for), strongest per proxy since the last frame.
    fn gather_rendered(&mut self, step: &StepView<'_>) {
        let period = step.rig_info.map_or(0.001, |r| r.period_s);
        for s in step.samples {
            if s.model_seq == 0 {
                continue;
            }
            let Some(m) = self.models.iter().find(|m| m.seq == s.model_seq) else { continue };
            for (p, imp) in m.proxies().iter().zip(s.proxy_contact_impulse_n_s.iter()) {
                if *imp == DVec3::ZERO {
                    continue;
                }
                let Some(h) = touching_hand(&p.shape, s) else { continue };
                let c = DrawnContact {
                    point_m: nearest_on_surface(&p.shape, s.hands[h].pos_world_m) + self.offset,
                    force_n: *imp / period,
                };
                let slot = self.rendered[..self.rendered_count].iter().position(|r| r.id == p.id);
                match slot {
                    Some(i) if self.rendered[i].contact.force_n.length() >= c.force_n.length() => {}
                    Some(i) => self.rendered[i].contact = c,
                    None if self.rendered_count < MAX_PROXIES => {
                        self.rendered[self.rendered_count] = Rendered { id: p.id, contact: c };
                        self.rendered_count += 1;
                    }
                    None => {}
                }
            }
        }
    }

    /// Writes this step into `buf` (at least the layout's `max_words` long): the header, hands,
    /// tensions, proxies and the scene's poses (which also refresh the status's counters); a
    /// crowd's drawn figures only with `figures_now` (else a [`FrameFinisher`] adds them). With
    /// `frame` it is a frame to send: a new sequence number, and the rendered contacts gathered
    /// since the last frame (then forgotten). Returns the frame's length in words.
    pub fn write(&mut self, buf: &mut [f32], step: &StepView<'_>, frame: bool, figures_now: bool) -> usize {
        let l = self.layout;
        if frame {
            self.seq = self.seq.wrapping_add(1);
        }
        // The tick's wall-clock time: now, less how long before this step the sample was read
        // (the step's time is the rig's clock at its start; the step's own compute time, tens of
        // microseconds, is not counted).
        let tick_wall_ms = if self.wall_clock && self.tick_t_s.is_finite() {
            let now = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64() * 1e3);
            now - (step.t_s - self.tick_t_s) * 1e3
        } else {
            0.0
        };
        let common = frame::Common {
            seq: self.seq,
            step: self.status.steps,
            tick: self.tick,
            tick_wall_ms,
            t_s: step.t_s,
            hands: &self.hands,
            tensions_n: step.rig_status.map(|r| &r.tensions_n),
            model: step.model,
            offset: self.offset,
        };
        frame::write_common(buf, &l, &common);
        let mut contacts = 0usize;
        {
            let mut poses = l.poses(buf, &mut self.status.counters, &mut contacts, figures_now);
            step.scene.pose(&mut poses);
            if frame {
                for r in &self.rendered[..self.rendered_count] {
                    let f = r.contact.force_n.length();
                    let mut on_shape = false;
                    for (k, p) in self.shape_proxies.iter().enumerate() {
                        if *p == Some(r.id) {
                            poses.shape_force(k, f);
                            on_shape = true;
                        }
                    }
                    if !on_shape && self.proxies_are_characters {
                        poses.character_push(r.id.body as usize, f);
                    }
                    poses.contact(r.contact);
                }
            }
        }
        buf[frame::GLOBALS_AT + 1] = contacts as f32;
        if frame {
            self.rendered_count = 0;
        }
        frame::words(&l, contacts)
    }
}

/// Adds to a frame what [`FrameMaker::write`] left for later: each character's drawn figure,
/// computed from the states the scene copied at the frame's step. Runs off the stepping thread
/// (one character's figure takes some 0.3 us).
#[derive(Clone, Debug)]
pub struct FrameFinisher {
    layout: Layout,
    figures: Option<Arc<Figures>>,
}

impl FrameFinisher {
    pub fn new(look: &Look) -> FrameFinisher {
        FrameFinisher {
            layout: Layout::for_look(look),
            figures: look.crowd.as_ref().and_then(|c| c.figures.clone()),
        }
    }

    /// How many figure states a frame of this look needs (0: it has no figures to add).
    pub fn states(&self) -> usize {
        if self.figures.is_some() {
            self.layout.characters
        } else {
            0
        }
    }

    /// Writes the joints of each character's figure (as many as `states` holds) into `frame`.
    pub fn finish(&self, frame: &mut [f32], states: &[FigureState]) {
        let Some((at, end)) = self.section(frame, states) else { return };
        for (slot, s) in frame[at..end].chunks_exact_mut(self.layout.character_floats).zip(states) {
            self.draw(slot, s);
        }
    }

    /// `frame` finished with `states` ([`FrameFinisher::finish`]) as the bytes a viewer gets
    /// (little-endian words), in `out`. `frame` is only read: the stepping thread that writes it
    /// finds it in its cache, not taken away by this thread's writes.
    pub fn to_bytes(&self, frame: &[f32], states: &[FigureState], out: &mut Vec<u8>) {
        out.clear();
        out.reserve(4 * frame.len());
        let put = |out: &mut Vec<u8>, words: &[f32]| {
            for w in words {
                out.extend_from_slice(&w.to_le_bytes());
            }
        };
        let Some((at, end)) = self.section(frame, states) else { return put(out, frame) };
        put(out, &frame[..at]);
        let mut slot = vec![0.0; self.layout.character_floats];
        for (c, s) in frame[at..end].chunks_exact(slot.len()).zip(states) {
            slot.copy_from_slice(c);
            self.draw(&mut slot, s);
            put(out, &slot);
        }
        // Characters without a state (none in a frame the view made) are sent as written.
        put(out, &frame[at + states.len().min(self.layout.characters) * slot.len()..]);
    }

    /// Where the characters' section of `frame` is, when there are figures to draw into it.
    fn section(&self, frame: &[f32], states: &[FigureState]) -> Option<(usize, usize)> {
        let l = &self.layout;
        let end = l.characters_at + l.characters * l.character_floats;
        (self.figures.is_some() && !states.is_empty() && l.character_floats > 0 && end <= frame.len())
            .then_some((l.characters_at, end))
    }

    /// One character's figure into its numbers.
    fn draw(&self, slot: &mut [f32], s: &FigureState) {
        let Some(figures) = &self.figures else { return };
        let mut joints = [DVec3::ZERO; MAX_JOINTS];
        let n = figures.world_joints(s, &mut joints);
        put_joints(slot, &joints[..n]);
    }
}

//! The binary frame: one flat array of little-endian 32-bit numbers per frame, at offsets fixed by
//! the scene's [`Look`] (the page computes them once from the description).
//!
//! ```text
//! word  0..4   header: magic "SPV1" (u32), layout id (u32), frame sequence (u32), flags (u32)
//! word  4..10  stamp: world step (u64), rig tick of the hand sample shown (u64; 0: none),
//!              that tick's wall-clock time (f64, ms since the Unix epoch; 0: not known)
//! word 10..14  t_s, contact count, proxy count, valid-hands mask (bit h: hand h valid)   (f32)
//! word 14..26  hands 0 and 1: position xyz, force felt xyz (scene frame)                 (f32)
//! word 26..34  string tensions, hand 0 strings 0..3 then hand 1 (N; NaN: not known)      (f32)
//! then         shapes: position xyz, rotation quaternion xyzw, per moving shape         (f32)
//!              contact force on each moving shape this frame (N)                        (f32)
//!              label states, one per label                                              (f32)
//!              characters: body position xyz, body rotation xyzw, control state,       (f32)
//!                push force (N), then per joint of the drawn figure its position xyz
//!              proxies (16): kind (0 none, 1 plane, 2 sphere, 3 capsule), a xyz, b xyz, radius
//!              gazes, one per look gaze: eyes xyz, unit direction xyz, point looked at xyz (f32)
//!              contacts (up to 32, the count above): point xyz, force xyz               (f32)
//! ```
//! A plane proxy's `a` is a point on it and `b` its outward normal; a sphere's `a` its centre; a
//! capsule's `a`, `b` its segment. Everything is in the scene frame (the link's frame plus the
//! look's `link_offset_m`). Only the used contacts are sent, so a frame's length varies.

use glam::DVec3;
use spidar_msg::{ContactModel, HandState, ProxyShape, HANDS, MAX_PROXIES, STRINGS};

use crate::look::{Look, Poses, CHARACTER_PUSH, CONTACT_FLOATS, GAZE_FLOATS, MAX_CONTACTS, SHAPE_FLOATS};

/// "SPV1" read as a little-endian u32.
pub const MAGIC: u32 = u32::from_le_bytes(*b"SPV1");
/// Where the stamp is: the world step, the rig tick, the tick's wall-clock time (two words each,
/// low word first; the time an f64's bits).
pub const STAMP_AT: usize = 4;
pub const GLOBALS_AT: usize = 10;
pub const HANDS_AT: usize = 14;
pub const HAND_FLOATS: usize = 6;
pub const TENSIONS_AT: usize = HANDS_AT + HANDS * HAND_FLOATS;
pub const PROXY_FLOATS: usize = 8;

/// Where each section of a frame starts (in 32-bit words).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Layout {
    pub id: u32,
    pub shapes: usize,
    pub labels: usize,
    pub characters: usize,
    pub character_floats: usize,
    pub shapes_at: usize,
    pub shape_force_at: usize,
    pub labels_at: usize,
    pub characters_at: usize,
    pub proxies_at: usize,
    pub gazes: usize,
    pub gaze_at: usize,
    pub contacts_at: usize,
    /// Words of a frame with every contact slot used.
    pub max_words: usize,
}

impl Layout {
    /// The layout of `look`'s frames, with an id that changes with the look (FNV-1a over its
    /// sizes and names): a page that described another look ignores the frames.
    pub fn for_look(look: &Look) -> Layout {
        let mut h: u32 = 0x811c_9dc5;
        let mut eat = |b: &[u8]| {
            for x in b {
                h ^= *x as u32;
                h = h.wrapping_mul(0x0100_0193);
            }
        };
        for s in &look.shapes {
            eat(s.name.as_bytes());
        }
        for l in &look.labels {
            eat(l.name.as_bytes());
        }
        for g in &look.gazes {
            eat(g.name.as_bytes());
        }
        if let Some(c) = &look.crowd {
            eat(&(c.characters as u64).to_le_bytes());
            for j in &c.joints {
                eat(j.name.as_bytes());
            }
        }
        Layout::of(look, h)
    }

    pub fn of(look: &Look, id: u32) -> Layout {
        let shapes = look.shapes.len();
        let labels = look.labels.len();
        let characters = look.crowd.as_ref().map_or(0, |c| c.characters);
        let character_floats = look.character_floats();
        let shapes_at = TENSIONS_AT + HANDS * STRINGS;
        let shape_force_at = shapes_at + shapes * SHAPE_FLOATS;
        let labels_at = shape_force_at + shapes;
        let characters_at = labels_at + labels;
        let proxies_at = characters_at + characters * character_floats;
        let gazes = look.gazes.len();
        let gaze_at = proxies_at + MAX_PROXIES * PROXY_FLOATS;
        let contacts_at = gaze_at + gazes * GAZE_FLOATS;
        Layout {
            id,
            shapes,
            labels,
            characters,
            character_floats,
            shapes_at,
            shape_force_at,
            labels_at,
            characters_at,
            proxies_at,
            gazes,
            gaze_at,
            contacts_at,
            max_words: contacts_at + MAX_CONTACTS * CONTACT_FLOATS,
        }
    }

    /// The sections a scene writes, over a frame buffer of `max_words`, with the contact count;
    /// the drawn figures too with `figures_now` ([`Poses::figures_now`]).
    pub fn poses<'a>(
        &self,
        buf: &'a mut [f32],
        counters: &'a mut [f64],
        contacts: &'a mut usize,
        figures_now: bool,
    ) -> Poses<'a> {
        let (head, rest) = buf.split_at_mut(self.shape_force_at);
        let shapes = &mut head[self.shapes_at..];
        let (shape_force, rest) = rest.split_at_mut(self.shapes);
        let (labels, rest) = rest.split_at_mut(self.labels);
        let (characters, rest) = rest.split_at_mut(self.characters * self.character_floats);
        let (gazes, contacts_buf) = rest[MAX_PROXIES * PROXY_FLOATS..].split_at_mut(self.gazes * GAZE_FLOATS);
        Poses {
            shapes,
            shape_force,
            labels,
            counters,
            characters,
            character_floats: self.character_floats,
            gazes,
            contacts: contacts_buf,
            contact_count: contacts,
            figures_now,
        }
    }
}

/// What every frame carries besides the scene's poses.
pub struct Common<'a> {
    pub seq: u32,
    /// The world step this frame shows (steps taken so far).
    pub step: u64,
    /// The rig tick whose hand sample the frame's hands are (0: none yet), and that tick's
    /// wall-clock time in ms since the Unix epoch (0: not known, e.g. on the virtual clock).
    pub tick: u64,
    pub tick_wall_ms: f64,
    pub t_s: f64,
    pub hands: &'a [HandState; HANDS],
    pub tensions_n: Option<&'a [[f64; STRINGS]; HANDS]>,
    pub model: &'a ContactModel,
    /// The link's frame in the scene's (added to every position from the link).
    pub offset: DVec3,
}

/// Writes the header and the sections every scene has (hands, tensions, proxies).
pub fn write_common(buf: &mut [f32], layout: &Layout, c: &Common<'_>) {
    let Common { seq, step, tick, tick_wall_ms, t_s, hands, tensions_n, model, offset } = *c;
    buf[0] = f32::from_bits(MAGIC);
    buf[1] = f32::from_bits(layout.id);
    buf[2] = f32::from_bits(seq);
    buf[3] = f32::from_bits(0);
    for (k, v) in [step, tick, tick_wall_ms.to_bits()].into_iter().enumerate() {
        buf[STAMP_AT + 2 * k] = f32::from_bits(v as u32);
        buf[STAMP_AT + 2 * k + 1] = f32::from_bits((v >> 32) as u32);
    }
    buf[GLOBALS_AT] = t_s as f32;
    buf[GLOBALS_AT + 1] = 0.0;
    buf[GLOBALS_AT + 2] = model.proxy_count as f32;
    let mut valid = 0u32;
    for (h, hs) in hands.iter().enumerate() {
        if hs.valid {
            valid |= 1 << h;
        }
        let o = HANDS_AT + h * HAND_FLOATS;
        put3(&mut buf[o..o + 3], hs.pos_world_m + offset);
        put3(&mut buf[o + 3..o + 6], hs.force_n);
    }
    buf[GLOBALS_AT + 3] = valid as f32;
    for h in 0..HANDS {
        for s in 0..STRINGS {
            buf[TENSIONS_AT + h * STRINGS + s] = tensions_n.map_or(f32::NAN, |t| t[h][s] as f32);
        }
    }
    for i in 0..MAX_PROXIES {
        let o = layout.proxies_at + i * PROXY_FLOATS;
        let p = &mut buf[o..o + PROXY_FLOATS];
        p.fill(0.0);
        let Some(proxy) = model.proxies().get(i) else { continue };
        match proxy.shape {
            ProxyShape::Plane { point_m, normal } => {
                p[0] = 1.0;
                put3(&mut p[1..4], point_m + offset);
                put3(&mut p[4..7], normal);
            }
            ProxyShape::Sphere { centre_m, radius_m } => {
                p[0] = 2.0;
                put3(&mut p[1..4], centre_m + offset);
                put3(&mut p[4..7], centre_m + offset);
                p[7] = radius_m as f32;
            }
            ProxyShape::Capsule { a_m, b_m, radius_m } => {
                p[0] = 3.0;
                put3(&mut p[1..4], a_m + offset);
                put3(&mut p[4..7], b_m + offset);
                p[7] = radius_m as f32;
            }
        }
    }
    // The scene's sections start clean: forces and pushes add up, contacts are counted.
    buf[layout.shape_force_at..layout.shape_force_at + layout.shapes].fill(0.0);
    for i in 0..layout.characters {
        buf[layout.characters_at + i * layout.character_floats + CHARACTER_PUSH] = 0.0;
    }
}

/// Words of a frame with `contacts` contacts.
pub fn words(layout: &Layout, contacts: usize) -> usize {
    layout.contacts_at + contacts.min(MAX_CONTACTS) * CONTACT_FLOATS
}

#[inline]
fn put3(s: &mut [f32], v: DVec3) {
    s[0] = v.x as f32;
    s[1] = v.y as f32;
    s[2] = v.z as f32;
}

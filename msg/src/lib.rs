//! Plain-data messages that cross between the rig (the 1 kHz rt-loop) and the world (the scene,
//! in its own process or on a thread), and their wire encoding ([`wire`]).
//!
//! Both sides import this crate and nothing else of each other, so `device` and `sim` stay leaves.
//! Everything here is `Copy`, fixed-size and allocation-free: a message goes through the link
//! (`spidar-link`: a bounded channel in one process, a datagram between processes) and never
//! blocks the tick.
//!
//! Frame: every position, velocity and force here is in the **world frame** (metres, y up, floor
//! at y = 0, the user at the origin facing -z). The rt-loop maps its rig frame to the world with
//! the rig file's `rig_to_world` transform before sending and back after receiving.
//! Time: `t_s` / `stamp_s` are seconds on the **rig's** loop clock (the real monotonic clock
//! since the loop started, or the virtual clock in tests). A world in another process has its
//! own clock; it stamps a model with the rig time it estimates from the newest sample (see
//! `docs/link.md`).

pub mod digest;
pub mod handshake;
pub mod strings;
pub mod wire;

use glam::DVec3;

/// Number of hands of a SPIDAR-H.
pub const HANDS: usize = 2;
/// Most contact proxies one `ContactModel` can carry.
pub const MAX_PROXIES: usize = 16;

/// Which sim body and part a proxy stands for, so the impulse the rt-loop applied to it can be
/// given back to that body.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct ProxyId {
    pub body: u16,
    pub part: u16,
}

/// Geometry of a local contact proxy, valid at `ContactModel::stamp_s`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ProxyShape {
    /// Half-space bounded by the plane through `point_m` with outward unit `normal`; the solid
    /// side is opposite the normal.
    Plane { point_m: DVec3, normal: DVec3 },
    /// Solid sphere.
    Sphere { centre_m: DVec3, radius_m: f64 },
    /// Solid capsule: the segment `a_m`..`b_m` swept by `radius_m`.
    Capsule { a_m: DVec3, b_m: DVec3, radius_m: f64 },
}

/// One contact proxy: a shape, its penalty gains, and its velocity for extrapolation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Proxy {
    pub id: ProxyId,
    pub shape: ProxyShape,
    /// Penalty stiffness on penetration depth.
    pub k_n_per_m: f64,
    /// Penalty damping on the approach speed (acts only while in contact).
    pub d_n_s_per_m: f64,
    /// Linear velocity of the proxy; the rt-loop moves the shape by `vel * age` before use.
    pub vel_m_per_s: DVec3,
    /// Bit 0: hand 0 may touch it; bit 1: hand 1 may touch it.
    pub hand_mask: u8,
}

impl Proxy {
    pub const BOTH_HANDS: u8 = 0b11;

    pub fn touches(&self, hand: usize) -> bool {
        self.hand_mask & (1 << hand) != 0
    }

    /// The same proxy moved by `dt_s` at its own velocity.
    pub fn extrapolated(&self, dt_s: f64) -> ProxyShape {
        let d = self.vel_m_per_s * dt_s;
        match self.shape {
            ProxyShape::Plane { point_m, normal } => ProxyShape::Plane { point_m: point_m + d, normal },
            ProxyShape::Sphere { centre_m, radius_m } => {
                ProxyShape::Sphere { centre_m: centre_m + d, radius_m }
            }
            ProxyShape::Capsule { a_m, b_m, radius_m } => {
                ProxyShape::Capsule { a_m: a_m + d, b_m: b_m + d, radius_m }
            }
        }
    }
}

/// The contact on one avatar hand as a local model for the rt-loop (the boxing scene, seed 000
/// section 3.4): the world's avatar hand, pulled toward the user's hand by the coupling spring,
/// touches something in the world with `force_n`; the user feels that force, and between two
/// world steps the loop carries it along with the user's hand motion as the linear update
/// `force_n + k_n_per_m (n.u)^2 ((at_m - x).u) u`, u the force's direction, n the normal
/// (see `spidar_rt::local`). All zero: no contact.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandContact {
    /// Contact force on the avatar's hand (world frame, newtons); zero when it touches nothing.
    pub force_n: DVec3,
    /// Unit contact normal, out of what the hand touches toward the hand (world frame).
    pub normal: DVec3,
    /// How fast the contact's normal force grows as the user's hand moves against `normal`
    /// (N/m): the contact's stiffness in series with the coupling spring.
    pub k_n_per_m: f64,
    /// The user's hand position (world frame) the world computed `force_n` for.
    pub at_m: DVec3,
    /// Power the touched body puts into the contact (W): the force on the avatar's hand times
    /// the velocity of the touched body's point. Positive when the virtual human pushes into the
    /// avatar's hand (a block meeting it, a punch): the rt-loop may give the user's hand that
    /// energy on top of what the hand itself put into the contact.
    pub source_w: f64,
}

impl HandContact {
    /// True when the avatar's hand touches something.
    pub fn touching(&self) -> bool {
        self.force_n != DVec3::ZERO
    }
}

/// A blow the virtual human landed on the avatar (boxing), as the world saw it at impact: the loop
/// makes the user's hands feel it (`spidar_rt::blow`: a held push along the blow, growing with its
/// momentum, plus a short decaying burst at impact whose amplitude grows with its speed). A model
/// carries the newest blow; `seq` tells a new one from the same one sent again. All zero: none yet.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Blow {
    /// Increases by one for every landed blow the world reports; 0: no blow yet.
    pub seq: u64,
    /// Where the fist met the avatar (world frame).
    pub point_m: DVec3,
    /// Unit direction of the blow: the fist's velocity relative to the part it struck, at impact.
    pub dir: DVec3,
    /// The fist's speed relative to the struck part at impact (m/s).
    pub speed_m_per_s: f64,
    /// The blow's effective momentum at impact (N s): the striking hand and forearm's mass times
    /// the impact speed.
    pub momentum_n_s: f64,
    /// True while the fist of this blow still touches the avatar (the held push lasts that long).
    pub in_contact: bool,
}

/// What the scene sends the rt-loop every simulation step: the local proxies near the hands, the
/// avatar hands' contacts as local models (boxing), plus a held per-hand force (the attenuated
/// "damage" force of hits on the avatar's body) and the newest blow landed on the avatar.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactModel {
    /// Increases by one for every model a scene sends.
    pub seq: u64,
    /// Loop-clock time at which the proxy geometry is valid.
    pub stamp_s: f64,
    pub proxies: [Proxy; MAX_PROXIES],
    pub proxy_count: u8,
    /// Per hand: the contact on the avatar's hand the user feels (scenes with an avatar; zero
    /// in the others). Rendered with the proxies, through the same safety chain.
    pub hand_contacts: [HandContact; HANDS],
    /// Extra force per hand added after rendering (world frame); faded like the rest when stale.
    pub extra_force_n: [DVec3; HANDS],
    /// The newest blow landed on the avatar (boxing; zero in the other scenes): rendered on both
    /// hands through the same safety chain.
    pub blow: Blow,
}

impl Default for ContactModel {
    fn default() -> Self {
        ContactModel {
            seq: 0,
            stamp_s: 0.0,
            proxies: [Proxy {
                id: ProxyId::default(),
                shape: ProxyShape::Sphere { centre_m: DVec3::ZERO, radius_m: 0.0 },
                k_n_per_m: 0.0,
                d_n_s_per_m: 0.0,
                vel_m_per_s: DVec3::ZERO,
                hand_mask: 0,
            }; MAX_PROXIES],
            proxy_count: 0,
            hand_contacts: [HandContact::default(); HANDS],
            extra_force_n: [DVec3::ZERO; HANDS],
            blow: Blow::default(),
        }
    }
}

impl ContactModel {
    pub fn proxies(&self) -> &[Proxy] {
        &self.proxies[..self.proxy_count as usize]
    }

    /// Appends a proxy; returns false (and drops it) when the model is full.
    pub fn push(&mut self, p: Proxy) -> bool {
        let n = self.proxy_count as usize;
        if n >= MAX_PROXIES {
            return false;
        }
        self.proxies[n] = p;
        self.proxy_count += 1;
        true
    }
}

/// One hand as the rt-loop measured it on one tick (world frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandState {
    /// Grip position in the world frame; `HandRecord::pos_rig_m` (rt-loop) is the same point in the rig.
    pub pos_world_m: DVec3,
    pub vel_world_m_per_s: DVec3,
    /// Force the rig commanded on the user's hand this tick, after safety.
    pub force_n: DVec3,
    /// False when the pose is not trustworthy (not homed, faulted, residual too large).
    pub valid: bool,
}

/// What the rt-loop sends the scene every tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandSample {
    /// Tick index since the loop started.
    pub tick: u64,
    /// Loop-clock time of the encoder read.
    pub t_s: f64,
    pub hands: [HandState; HANDS],
    /// `seq` of the contact model the impulses below were computed against (0: none).
    pub model_seq: u64,
    /// Impulse the rig really applied to the user's hands through each proxy of that model this
    /// tick (index as in `proxies`), summed over both hands: minus the rendered penalty force
    /// after the ramp, the stale-model fade, the rig's force clamp and the tension allocation's
    /// scaling, times the tick period. It is what the physical hand received, so a scene whose
    /// proxies stand for things the *user* touches directly (walls, a crowd pushed by the hands)
    /// applies this one: the body gets exactly the reaction of what the user felt, and momentum
    /// between the person and the world is consistent. Bounded by the rig's force limit.
    pub proxy_impulse_n_s: [DVec3; MAX_PROXIES],
    /// Impulse of the virtual contact itself through each proxy this tick (index as in
    /// `proxies`), summed over both hands: minus the rendered penalty force (stiffness already
    /// limited by the renderer) times the tick period, scaled by the loop's gain (ramp x
    /// stale-model fade; zero when not active, so a stale or faded model acts on nothing) but
    /// NOT by the rig's force clamp or the allocation's scaling. A scene where a simulated body
    /// stands between the user and the world (the boxing avatar's hand, coupled to the user's
    /// hand by a spring) applies this one: the virtual human receives the full contact force of
    /// the avatar's hand, while the user feels it only as far as the rig can display it (seed
    /// 000, sections 3.4 and 3.12). Equals `proxy_impulse_n_s` whenever nothing was clamped.
    pub proxy_contact_impulse_n_s: [DVec3; MAX_PROXIES],
}

impl Default for HandSample {
    fn default() -> Self {
        HandSample {
            tick: 0,
            t_s: 0.0,
            hands: [HandState::default(); HANDS],
            model_seq: 0,
            proxy_impulse_n_s: [DVec3::ZERO; MAX_PROXIES],
            proxy_contact_impulse_n_s: [DVec3::ZERO; MAX_PROXIES],
        }
    }
}

/// Strings per hand.
pub const STRINGS: usize = 4;

/// What the world needs to know of the rig to show it: sent once when the link connects.
/// World frame, like everything here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigInfo {
    /// Tick period of the loop.
    pub period_s: f64,
    /// Where each string leaves the frame, per hand (world frame).
    pub anchors_m: [[DVec3; STRINGS]; HANDS],
    /// Each hand's home point (world frame).
    pub home_m: [DVec3; HANDS],
    /// The range of commanded tension, per hand (for colouring strings by tension).
    pub tension_min_n: [f64; HANDS],
    pub tension_max_n: [f64; HANDS],
    /// The largest force the rig renders on a hand.
    pub force_limit_n: [f64; HANDS],
    /// Radius of the sphere that stands for each fist in contact rendering.
    pub grip_radius_m: [f64; HANDS],
    /// The user's eye point (world frame), for a first-person view.
    pub eye_m: DVec3,
    /// The rig's screen, if its rig file places one (world frame).
    pub display: DisplayInfo,
    /// When a string counts as near another hand's string or the user's forearm (the rig file's
    /// `near_strings`; the forearm's direction in the world frame), for the live view's marks.
    pub clearance: strings::StringClearance,
}

/// The rig's screen (world frame): the rectangle the user's-eye view is drawn through from
/// `RigInfo::eye_m` (an off-axis perspective), the eyes' separation and the stereo format.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DisplayInfo {
    /// False: the rig file places no screen (the rest is zero).
    pub present: bool,
    /// The picture's corners as seen from the eye.
    pub lower_left_m: DVec3,
    pub lower_right_m: DVec3,
    pub upper_left_m: DVec3,
    pub eye_separation_m: f64,
    /// 0 mono, 1 side by side, 2 top and bottom, 3 anaglyph.
    pub stereo: u8,
}

impl Default for RigInfo {
    fn default() -> Self {
        RigInfo {
            period_s: 0.001,
            anchors_m: [[DVec3::ZERO; STRINGS]; HANDS],
            home_m: [DVec3::ZERO; HANDS],
            tension_min_n: [0.0; HANDS],
            tension_max_n: [0.0; HANDS],
            force_limit_n: [0.0; HANDS],
            grip_radius_m: [0.0; HANDS],
            eye_m: DVec3::ZERO,
            display: DisplayInfo::default(),
            clearance: strings::StringClearance::default(),
        }
    }
}

/// The rig's lifecycle as the world sees it (`spidar_rt::Lifecycle`, plus a stop under way).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
#[repr(u8)]
pub enum RigState {
    #[default]
    Unconfigured = 0,
    Inactive = 1,
    Active = 2,
    Faulted = 3,
    Stopping = 4,
}

/// A low-rate summary of the rig for the world's viewers and recorder (a few tens of hertz): what
/// a heads-up display shows and what the strings are doing.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RigStatus {
    /// Tick index and loop-clock time of the newest tick it summarises.
    pub tick: u64,
    pub t_s: f64,
    pub state: RigState,
    /// Achieved tick rate and wake-up lateness p99 over the last window.
    pub rate_hz: f64,
    pub lateness_p99_s: f64,
    /// Force the rig applied to each hand on the newest tick (world frame).
    pub force_n: [DVec3; HANDS],
    /// Commanded tension of every string on the newest tick, per hand.
    pub tensions_n: [[f64; STRINGS]; HANDS],
    /// Running counts since the rig started.
    pub faults: u64,
    pub device_errors: u64,
    pub stale_ticks: u64,
    pub clamped_ticks: u64,
    pub misses: u64,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn push_stops_at_capacity() {
        let mut m = ContactModel::default();
        let p = m.proxies[0];
        for _ in 0..MAX_PROXIES {
            assert!(m.push(p));
        }
        assert!(!m.push(p));
        assert_eq!(m.proxies().len(), MAX_PROXIES);
    }

    #[test]
    fn extrapolation_moves_every_shape_by_velocity_times_age() {
        let v = DVec3::new(1.0, -2.0, 0.5);
        let mk = |shape| Proxy {
            id: ProxyId::default(),
            shape,
            k_n_per_m: 1.0,
            d_n_s_per_m: 0.0,
            vel_m_per_s: v,
            hand_mask: Proxy::BOTH_HANDS,
        };
        let d = v * 0.01;
        match mk(ProxyShape::Sphere { centre_m: DVec3::ONE, radius_m: 0.1 }).extrapolated(0.01) {
            ProxyShape::Sphere { centre_m, radius_m } => {
                assert_eq!(centre_m, DVec3::ONE + d);
                assert_eq!(radius_m, 0.1);
            }
            _ => panic!("shape changed"),
        }
        match mk(ProxyShape::Capsule { a_m: DVec3::X, b_m: DVec3::Y, radius_m: 0.1 }).extrapolated(0.01) {
            ProxyShape::Capsule { a_m, b_m, .. } => assert_eq!((a_m, b_m), (DVec3::X + d, DVec3::Y + d)),
            _ => panic!("shape changed"),
        }
        match mk(ProxyShape::Plane { point_m: DVec3::ZERO, normal: DVec3::Y }).extrapolated(0.01) {
            ProxyShape::Plane { point_m, normal } => assert_eq!((point_m, normal), (d, DVec3::Y)),
            _ => panic!("shape changed"),
        }
    }
}

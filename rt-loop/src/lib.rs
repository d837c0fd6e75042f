//! spidar's hard-real-time side: the 1 kHz haptic loop and the rig model it runs on.
//!
//! A tick reads the encoders, computes both hand poses from the string lengths, renders penalty
//! forces against the contact proxies the scene sent, applies the safety rules and allocates
//! string tensions, then writes DA volts. Phases live in their own modules, in the order they
//! run: [`kinematics`], [`velocity`], [`render`] (and [`local`] for the avatar hands' contacts),
//! [`safety`], [`tension`], [`produced`] (the produced force kept within the limit); [`tick`] strings them together with the lifecycle (whose states,
//! faults, commands and events are named in [`control`]), [`runner`] adds the device, the clock,
//! the channels and the link to the world ([`status`]: what the rig tells the world about itself).

pub mod blow;
pub mod boards;
pub mod bounds;
pub mod clock;
pub mod control;
pub mod display;
/// Configuration loading lives in its own crate so `sim` can share it without depending on the rt-loop.
pub use spidar_config as config;
pub mod kinematics;
pub mod local;
pub mod produced;
pub mod render;
pub mod rig;
pub mod rt_thread;
pub mod runner;
pub mod safety;
pub mod status;
pub mod summary;
pub mod telemetry;
pub mod tension;
pub mod tick;
pub mod velocity;

pub use clock::{Clock, MonotonicClock, VirtualClock};
pub use config::ConfigError;
pub use rig::Rig;
pub use runner::{Endpoints, FarEnds, Lifeline, RtLoop};
pub use tick::{Command, Counters, Event, FaultReason, Lifecycle, TickCore};

/// Errors of the rt-loop crate (set-up time only; the tick itself reports by counters and events).
#[derive(Debug, thiserror::Error)]
pub enum RtError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("hand {hand}: the anchor geometry cannot be used: {why}; check anchor_m in the rig file")]
    Geometry { hand: usize, why: String },
}

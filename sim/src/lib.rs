//! spidar-sim: the physics world behind the SPIDAR-H.
//!
//! Articulated bodies in reduced coordinates, stepped with Featherstone's articulated-body
//! algorithm (`aba`), penalty contacts (`contact`, `collide`), joint springs toward a default
//! pose made implicit for stability (`passive`), and bodies and scenes described in RON (`desc`).
//! `Model` is immutable and shared; `State` is what is integrated and what a prediction copies;
//! `Workspace` holds everything derived and is one per thread. `step = forward + integrate`.
//!
//! This crate is a leaf: it knows the plain-data messages of `spidar-msg` and nothing of the
//! rt-loop or the devices.

// Index loops mirror the matrix notation of the algorithms; `!(x > 0.0)` deliberately catches NaN.
#![allow(clippy::needless_range_loop, clippy::neg_cmp_op_on_partial_ord)]

pub mod aba;
pub mod boxer;
pub mod character;
pub mod collide;
pub mod contact;
pub mod crba;
pub mod desc;
pub mod impulse;
pub mod joint;
pub mod model;
pub mod passive;
pub mod rnea;
pub mod spatial;
pub mod state;
pub mod step;

pub use desc::{boxing_scene, load_scene};
pub use model::{Model, Part, Side};
pub use state::{Contact, State, Workspace};
pub use step::{forward, forward_dynamics, integrate, step, Predictor};

/// Errors building a world.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error(transparent)]
    Config(#[from] spidar_config::ConfigError),
    #[error("{path}: cannot read the file: {message}")]
    Io { path: String, message: String },
    #[error("cannot build the model: {0}")]
    Build(String),
}

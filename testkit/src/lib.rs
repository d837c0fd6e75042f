//! What the test binaries of spidar share: devices that misbehave as real hardware does
//! ([`Garbling`]), scenes that send what a broken world could ([`HostileScene`]), and the harness
//! that kills a recording process mid-write ([`spawn_test_child`], [`kill_once_written`]),
//! property tests that run the same cases everywhere ([`proptest_config`]), and whether a test
//! that drives node and chromium can run here ([`node`]).
//!
//! Why it exists: these were copied from one test binary to the next. What it must never do:
//! become a dependency of the product (only `[dev-dependencies]` name it), or hide a hazard the
//! real thing has (a test device behaves as the hardware it stands for, hazards included).

mod garbling;
mod hostile;
mod kill;
pub mod node;
mod props;

pub use garbling::Garbling;
pub use hostile::{HostileScene, Hostility};
pub use kill::{kill_once_written, spawn_test_child};
pub use props::proptest_config;

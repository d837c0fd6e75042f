//! The library behind the `spidar` binary: scenes on the far side of the rt-loop's channels,
//! sessions that wire a device, the loop, a scene and telemetry together, and the benchmarks.
//! The binary (`main.rs`) only parses arguments and calls into here.

pub mod bench;
pub mod calib;
pub mod eval;
pub mod eval_impacts;
pub mod hardware;
pub mod scene;
pub mod session;

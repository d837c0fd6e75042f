//! The rig runtime: what `spidar run` is, as a library. A session wires a device, the 1 kHz loop
//! (`spidar_rt`), a world and the telemetry consumer together, on the real clock (`session`'s
//! live session, with the supervisor that makes the boards safe when this process dies) or on the
//! virtual clock (bit-identical runs for tests and evaluations).
//!
//! Where things are:
//! - `session`: live and virtual sessions; `summary` and `report`: what a session says at the end
//!   (text, JSON, exit status); `recording`: what `run --record` writes about the session.
//! - Worlds: `child_world` (a `spidar world` child process, watched and restarted),
//!   `world_process` (the world process itself), `scene_thread` (a world on a thread of the rig's
//!   process).
//! - `calibration`: `spidar calib`'s session, the same loop calibrating (strings at minimum
//!   tension), on the real-time thread under the supervisor on real boards.
//! - Safety around the process: `supervisor` (the parent that writes zero to the boards when the
//!   rig process dies or hangs), `signals` (stop requests), `term` (output that never panics).
//! - `plan`: `spidar run`'s options checked into a plain plan; `run`: runs it.
//! - Devices: `hardware` (board drivers from options, the emulator, discovery); `scripts` (the
//!   simulated user's boxing scripts); `rigpath` (which rig file a command uses).
//! - Playback: `replay` and `replay_view` (`spidar replay`, `export`, `plot`).
//!
//! The binary (`tools/`, `spidar`) parses arguments and calls into here; the hardware-in-the-loop
//! tests (`tests/`) and the measurements (`lab/`) use the same code.

pub mod calibration;
pub mod child_world;
pub mod hardware;
pub mod placement;
pub mod plan;
pub mod recording;
pub mod replay;
pub mod replay_view;
pub mod report;
pub mod rigpath;
pub mod run;
pub mod scene_thread;
pub mod scripts;
pub mod session;
pub mod signals;
pub mod summary;
pub mod supervisor;
pub mod term;
pub mod world_process;

//! The library behind the `spidar` binary: sessions that wire a device, the loop, a world and
//! telemetry together, the world process (`spidar world`) and the child world of `spidar run`, the simulated user's scripts, the evaluations and the benchmarks.
//! The binary (`main.rs`) only parses arguments and calls into here.

pub mod bench;
pub mod bench_record;
pub mod bench_replay;
pub mod bench_view;
pub mod calib;
pub mod child_world;
pub mod crowd_run;
pub mod eval;
pub mod eval_impacts;
pub mod eval_poses;
pub mod hardware;
pub mod recording;
pub mod replay_view;
pub mod report;
pub mod rigpath;
pub mod scene_thread;
pub mod scripts;
pub mod session;
pub mod signals;
pub mod supervisor;
pub mod term;
pub mod world_process;

//! Measurements of spidar on the user's path: the evaluations (`spidar eval`: the boxing paper's
//! reactions and Table IV, the characters paper's impacts and poses) and the benchmarks (`spidar
//! bench`: the loop against a bare sleep loop, the link, recording, the live view, replay), with
//! the text they print; and the reaction study with people (`spidar study reactions`: the
//! paper's Table IV experiment served as a page). Each runs the product's own runtime
//! (`spidar_runtime`): the simulated rig, the rt-loop and the world a person meets, never a side
//! path.

pub mod bench;
pub mod bench_age;
pub mod bench_record;
pub mod bench_replay;
pub mod bench_view;
pub mod browser;
pub mod cpus;
pub mod crowd_run;
pub mod eval;
pub mod eval_blows;
pub mod eval_impacts;
pub mod eval_poses;
pub mod spar;
pub mod study;
pub mod study_page;
pub mod zwidth;
pub mod zwidth_plot;
pub mod zwidth_sweep;

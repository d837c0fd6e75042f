//! Recording through the real serial path: the calibrating rt-loop drives the `uart` driver with
//! its default options (an 800 us reply deadline), which talks over a pseudo-terminal to the
//! board emulator (on a thread of this process), which runs the simulated rig with a
//! wrong-on-purpose truth. The loop runs on the virtual clock, paced by the replies; the emulator
//! advances the rig one period per servo tick it receives (`PlantClock::PerTick`), so what is
//! recorded does not depend on this machine's timing; the faults (late and lost replies) are
//! switched on the emulator at a given request. No wall-clock assertion: a reply the machine
//! makes late by accident is one more tick left out, which is what this test is about. (The
//! same loop on its real-time thread, behind `spidar calib`, is `tools/tests/calib_cli.rs`.)

use std::path::PathBuf;
use std::time::Duration;

use glam::DVec3;
use spidar_calib::fit::{fit_hand, observations, FitOptions};
use spidar_calib::jig::JigFile;
use spidar_calib::model::HandGeometry;
use spidar_calib::record::{Answer, Operator, Plan, RecordOptions, Recorder, Request};
use spidar_calib::sim::{sim_rig, truth_geometry, SimTruthOptions};
use spidar_calib::ticks::{TickSource, Ticks, VirtualLoop};
use spidar_calib::CalibError;
use spidar_device::emulator::{Control, Emulator, EmulatorOptions, PlantClock};
use spidar_device::sim::{Script, Segment};
use spidar_device::uart::{SerialPath, UartDevice, UartOptions};
use spidar_device::Device;
use spidar_rt::Rig;

fn link(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("spidar-calib-emu-{}-{name}", std::process::id()))
}

/// Moves the emulator's simulated hand to each requested point (and holds it there stiffly) and
/// answers at once; `fault` runs at the given request (0-based).
struct EmulatorHand {
    control: Control,
    requests: usize,
    fault_at: usize,
    fault: fn(&Control),
}

impl<S: TickSource> Operator<S> for EmulatorHand {
    fn request(&mut self, _: &mut Ticks<S>, hand: usize, req: &Request) -> Result<Answer, CalibError> {
        let at = match req {
            Request::Home { at_m } | Request::Jig { at_m, .. } => *at_m,
            Request::Free { suggest_m, .. } => *suggest_m,
        };
        // A minimum-jerk reach at arm speed, then hold (not a jump: no counter may move further
        // in one tick than a grip can).
        let from = self.control.truth().hands[hand].pos_m;
        let script = Script::from_segments(
            vec![
                Segment::Reach { to_m: at.to_array(), duration_s: 0.3 + 2.0 * from.distance(at) },
                Segment::Hold { at_m: at.to_array(), for_s: 1e6 },
            ],
            false,
        );
        self.control.boards().rig_mut().try_set_script(hand, script).unwrap();
        if self.requests == self.fault_at {
            (self.fault)(&self.control);
        }
        self.requests += 1;
        Ok(Answer::Ready)
    }
    fn tell(&mut self, _: &str) {}
}

fn jig() -> JigFile {
    JigFile::load(std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/jig-spidar-h.ron")))
        .unwrap()
}

/// The emulator in front of a simulated rig whose truth `opts` perturbs, advancing one period
/// per servo tick, and the `uart` driver opened on it as `spidar calib record --device uart`
/// opens it: default options.
fn emulated(opts: SimTruthOptions, name: &str) -> (Emulator, UartDevice<SerialPath>, [HandGeometry; 2]) {
    let rig = Rig::default_rig();
    let truth = truth_geometry(&rig, &opts);
    let sim = sim_rig(&rig, &truth, opts.noise_counts, opts.seed).unwrap();
    let eo = EmulatorOptions { plant: PlantClock::PerTick, ..Default::default() };
    let emu = Emulator::spawn(sim, eo, &link(name)).unwrap();
    // The boards' 20 ms to answer the enumeration is a wall-clock deadline that a loaded test
    // machine can miss before the emulator's thread runs: give the open a quarter second, as the
    // HIL tests over the pty do.
    let uo = UartOptions { enumerate_timeout: Duration::from_millis(250), ..Default::default() };
    let mut dev = UartDevice::on_port(emu.symlink().to_str().unwrap(), uo).unwrap();
    dev.open().unwrap();
    (emu, dev, truth)
}

#[test]
fn a_burst_of_late_and_lost_replies_during_record_does_not_abort_it() {
    let rig = Rig::default_rig();
    let (emu, dev, truth) = emulated(
        SimTruthOptions { seed: 11, anchor_error_m: 0.03, mpc_error: 0.05, noise_counts: 0.5 },
        "burst",
    );
    let mut rec = Recorder::on_virtual_loop(dev, &rig, RecordOptions::default(), true).unwrap();
    // While the third pose is recorded, once its grip has arrived (1500 servo ticks after the
    // request): 40 replies 5 ms late, then 150 lost in a row (more than the 50 in a row that used
    // to end the session).
    let mut hand = EmulatorHand {
        control: emu.control().clone(),
        requests: 0,
        fault_at: 2,
        fault: |c| {
            let c = c.clone();
            let from = c.stats().ticks;
            std::thread::spawn(move || {
                while c.stats().ticks < from + 1500 {
                    std::thread::sleep(Duration::from_millis(1));
                }
                c.delay_replies(40, Duration::from_millis(5));
                while c.pending_faults() > 0 {
                    std::thread::sleep(Duration::from_millis(1));
                }
                c.drop_replies(150);
            });
        },
    };
    let plan =
        Plan { hands: vec![0], jig: Some(jig()), free_per_hand: 0, free_half_extent_m: DVec3::splat(0.3) };
    let session = rec.record_session(&mut hand, &plan, "emulated UART boards").unwrap();
    let stats = rec.loop_stats();
    let counters = *rec.ticks().source_mut().counters();
    rec.finish().unwrap();
    assert_eq!(emu.control().pending_faults(), 0, "every injected fault was served");
    assert!(stats.late_or_bad >= 150, "late and lost replies left out and counted: {stats}");
    assert!(stats.longest_outage_ticks >= 100, "{stats}");
    // The loop's own rules: the lost run faulted it (outputs safe), and it recovered by itself.
    assert!(counters.faults >= 1 && counters.late_replies >= 1, "{counters:?}");
    assert_eq!(session.poses.len(), 9, "home and the 8 jig points");
    // The outputs are off again (every motor command zero) and the data are good.
    assert!(emu.control().boards().motor_commands().iter().all(|&c| c == 0));
    let fit = fit_hand(0, &rig.hands[0], &observations(&session, 0), &FitOptions::default()).unwrap();
    assert!(fit.quality.clean(), "{:?}", fit.quality);
    for i in 0..4 {
        let err = fit.geometry.anchors_m[i].distance(truth[0].anchors_m[i]);
        assert!(err < 1e-3, "anchor {i}: {:.3} mm from the truth", err * 1e3);
    }
}

#[test]
fn a_board_that_stays_silent_ends_the_session_with_the_poses_kept() {
    let rig = Rig::default_rig();
    let (emu, dev, _) = emulated(SimTruthOptions { seed: 12, ..SimTruthOptions::default() }, "silent");
    // Lost after 0.3 s of silence (300 failed exchanges in a row).
    let ro = RecordOptions { lost_after_s: 0.3, ..RecordOptions::default() };
    let mut rec = Recorder::on_virtual_loop(dev, &rig, ro, true).unwrap();
    let mut hand = EmulatorHand {
        control: emu.control().clone(),
        requests: 0,
        fault_at: 3,
        fault: |c| c.set_silent(true),
    };
    let plan =
        Plan { hands: vec![0], jig: Some(jig()), free_per_hand: 0, free_half_extent_m: DVec3::splat(0.3) };
    let mut session = spidar_calib::session::SessionFile::new(&rig.name, "", "emu", plan.session_plan(None));
    let mut saved = Vec::new();
    let e = rec.record_plan(&mut hand, &plan, &mut session, &mut |s| {
        saved.push(s.poses.len());
        Ok(())
    });
    assert!(matches!(e, Err(CalibError::BoardLost(_))), "{e:?}");
    assert_eq!(session.poses.len(), 3, "the poses before the silence are kept");
    assert_eq!(saved, [1, 2, 3], "and were saved one by one");
    assert!(rec.loop_stats().longest_outage_ticks >= 300);
    // The loop's switch-off at the end: the boards heard nothing (silent), so they still hold
    // the minimum tension; back on the line, the next session's start commands them again.
    assert!(rec.switch_off().is_err(), "a silent board cannot confirm the zero");
}

#[test]
fn the_end_of_a_session_leaves_zero_on_every_motor_also_when_its_replies_are_lost() {
    let rig = Rig::default_rig();
    let (emu, dev, _) = emulated(SimTruthOptions { seed: 13, ..SimTruthOptions::default() }, "off");
    let mut ticks = Ticks::new(VirtualLoop::start(dev, &rig, true).unwrap(), &rig, 2.0);
    for _ in 0..10 {
        ticks.tick().unwrap();
    }
    assert!(emu.control().boards().motor_commands().iter().any(|&c| c != 0), "strings held");
    // The replies to the last holding ticks and to the switch-off are lost (the boards still
    // apply the commands): the loop's stop writes zero regardless.
    emu.control().drop_replies(40);
    let _ = ticks.switch_off();
    assert!(emu.control().boards().motor_commands().iter().all(|&c| c == 0), "outputs left on");
}

//! The rig's screen, the headset and the bodies drawn as people, in Debian's chromium
//! (`tests/browser/display.mjs`), from `spidar run`'s path: the simulated rig, the rt-loop and the
//! child world process serving the view, on a rig file that places a screen.
//!
//! The geometry the pages are checked against is computed here, from the rig file the session
//! runs on (never from the page's code): where the ray from each eye to a point crosses the
//! screen, and where the image of a sphere (a grip) centres on it.

use glam::DVec3;
use serde_json::{json, Value};
use spidar_rt::display::Display;
use spidar_rt::rig::DEFAULT_RIG_RON;
use spidar_rt::Rig;

use super::view::{browser_here, node_script, one_at_a_time, test_certificate, RunPath};

/// The default rig with the eye lower and closer than its default, and a screen off-centre and
/// turned on all three axes: the grips and the virtual human's head fall well inside it.
pub(super) const SCREEN_RIG_TAIL: &str = "    eye_m: Some((0.0, 0.2, 0.45)),
    display: Some((
        // Off-centre and tilted: yawed 12 degrees, pitched -8, rolled 3.
        screen: Centre(centre_m: (0.15, 0.07, -0.7), size_m: (1.6, 1.2), yaw_deg: 12.0, pitch_deg: -8.0, roll_deg: 3.0),
        // The viewer's eyes.
        eye_separation_m: 0.063,
        // What the screen takes.
        stereo: Mono,
    )),
)
";

pub(super) fn screen_rig_text() -> String {
    let cut = DEFAULT_RIG_RON.rfind("    eye_m: Some(").expect("the default rig's eye_m");
    format!("{}{}", &DEFAULT_RIG_RON[..cut], SCREEN_RIG_TAIL)
}

pub(super) fn screen_rig() -> Rig {
    Rig::from_str(&screen_rig_text(), "the test's rig with a screen").unwrap()
}

/// Where the image of a sphere of radius `r_m` centred at `c` (seen from `eye`) centres on the
/// screen, (u, v) in metres: the silhouette cone cut by the screen's plane is an ellipse whose
/// centre is the midpoint of the two generators in the plane of the cone's axis and the screen's
/// normal. (It is not where the centre's own ray crosses: a near sphere seen at an angle images
/// off that point by a few millimetres.)
fn sphere_image_centre(d: &Display, eye: DVec3, c: DVec3, r_m: f64) -> Option<(f64, f64)> {
    let n = d.normal();
    let a = (c - eye).normalize();
    let alpha = (r_m / (c - eye).length()).asin();
    let w = n - a * n.dot(a);
    if w.length() < 1e-9 {
        return d.crossing(eye, c);
    }
    let w = w.normalize();
    let p = d.crossing(eye, eye + a * alpha.cos() + w * alpha.sin())?;
    let q = d.crossing(eye, eye + a * alpha.cos() - w * alpha.sin())?;
    Some(((p.0 + q.0) / 2.0, (p.1 + q.1) / 2.0))
}

/// Each eye's rectangle of the page (x, y, w, h in px, y down) in a stereo format, as a 3D
/// display's frame packing has it: left eye left or on top.
fn eye_views(format: &str, w: f64, h: f64) -> Vec<(f64, f64, f64, f64)> {
    match format {
        "side-by-side" => vec![(0.0, 0.0, w / 2.0, h), (w / 2.0, 0.0, w / 2.0, h)],
        "top-bottom" => vec![(0.0, 0.0, w, h / 2.0), (0.0, h / 2.0, w, h / 2.0)],
        "anaglyph" => vec![(0.0, 0.0, w, h); 2],
        _ => vec![(0.0, 0.0, w, h)],
    }
}

/// Answers the page's question `screen_pixels`: for each point (scene frame) and each eye, the
/// pixel where the eye's ray to it crosses the screen and, for a sphere, where its image centres.
fn screen_pixels(rig: &Rig, link_offset_m: DVec3, q: &Value) -> Value {
    let d = rig.display.expect("the test's rig has a screen");
    let (w, h) = (q["w"].as_f64().unwrap(), q["h"].as_f64().unwrap());
    let format = q["format"].as_str().unwrap();
    let views = eye_views(format, w, h);
    let eyes = if views.len() == 1 { vec![rig.eye_m] } else { d.eyes(rig.eye_m).to_vec() };
    let px = |(x0, y0, vw, vh): (f64, f64, f64, f64), (u, v): (f64, f64)| json!({"x": x0 + u / d.width_m * vw, "y": y0 + (1.0 - v / d.height_m) * vh});
    let points = q["points"].as_array().unwrap();
    let out: Vec<Value> = points
        .iter()
        .map(|p| {
            let s: Vec<f64> = p["pos"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
            let p_rig = rig.rig_to_world.point_to_rig(DVec3::new(s[0], s[1], s[2]) - link_offset_m);
            let radius = p["radius"].as_f64();
            let per_eye: Vec<Value> = eyes
                .iter()
                .zip(&views)
                .map(|(eye, view)| {
                    let c = d.crossing(*eye, p_rig).expect("the point is beyond the eye, toward the screen");
                    let margin = 0.12;
                    assert!(
                        c.0 > margin && c.0 < d.width_m - margin && c.1 > margin && c.1 < d.height_m - margin,
                        "{} crosses the screen at ({:.3}, {:.3}) m: too near its edge (the test's screen must hold it)",
                        p["name"],
                        c.0,
                        c.1
                    );
                    let image = radius.and_then(|r| sphere_image_centre(&d, *eye, p_rig, r));
                    json!({"centre": px(*view, c), "image": image.map(|i| px(*view, i)),
                        "view": {"x": view.0, "y": view.1, "w": view.2, "h": view.3},
                        "radius_px": radius.map(|r| r / (p_rig - *eye).length() * (d.lower_left_m - *eye).dot(-d.normal()) / d.width_m * view.2)})
                })
                .collect();
            json!({"name": p["name"], "eyes": per_eye})
        })
        .collect();
    json!({"points": out, "grip_radius_m": rig.hands[0].grip_radius_m})
}

/// The user's-eye view on a rig screen that is off-centre and tilted: the page draws each grip
/// and the virtual human's head where the ray from the eye to it crosses the screen (its
/// projection within 2 px of that crossing, the grips' drawn pixels centred within 2 px of their
/// images), mono and for each eye in each stereo format (side by side, top and bottom,
/// anaglyph), on `spidar run`'s path.
#[test]
fn display_draws_the_rig_frame_through_the_screen_from_the_eye() {
    let _one = one_at_a_time();
    if !browser_here("display_draws_the_rig_frame_through_the_screen_from_the_eye") {
        return;
    }
    let rig = screen_rig();
    let run = RunPath::start_on("boxing", "hold", rig.clone());
    let scene = run.get("/scene.json");
    let off: Vec<f64> =
        scene["link_offset_m"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let link_offset_m = DVec3::new(off[0], off[1], off[2]);
    node_script("display.mjs", &["screen", &run.url], |q| match q["ask"].as_str().unwrap() {
        "screen_pixels" => screen_pixels(&rig, link_offset_m, q),
        other => json!({"error": format!("unknown question {other}")}),
    });
    let sum = run.finish();
    assert!(sum.clean_stop, "{sum}");
}

/// The headset: in Debian's chromium with a WebXR headset emulated inside the page (npm `iwer`),
/// on `spidar run`'s path, the page enters an immersive session; with the emulated controllers
/// held on the grips (in the headset's floor frame, turned and moved from the scene's) a trigger
/// press registers the headset to the rig; then, for the headset where it started and moved and
/// turned, each eye draws the virtual human (further right in the left eye: stereo) and draws each
/// grip centred within 3 px of where the headset's geometry (its pose, eye separation and field of
/// view, computed by the test) images the controller on it: the grips are where the hands are.
/// The page comes over HTTPS and its frames over a secure WebSocket (`--view-tls`), and the
/// world keeps the pictures the headset drew as the headset's ages.
#[test]
fn display_headset_enters_registers_and_draws_the_grips_at_the_hands() {
    let _one = one_at_a_time();
    if !browser_here("display_headset_enters_registers_and_draws_the_grips_at_the_hands") {
        return;
    }
    // Served over HTTPS as for a headset on the network, with a certificate made for the test.
    let (dir, cert_pem, key_pem, _) = test_certificate("headset-tls");
    let tls = format!("{},{}", cert_pem.display(), key_pem.display());
    let run = RunPath::start_with("boxing", "hold", screen_rig(), &["--view-tls".into(), tls]);
    assert!(run.url.starts_with("https://"), "the view is served over HTTPS: {}", run.url);
    node_script(
        "display.mjs",
        &["headset", &run.url],
        |q| json!({"error": format!("unexpected question {q}")}),
    );
    let _ = std::fs::remove_dir_all(&dir);
    let sum = run.finish();
    assert!(sum.clean_stop, "{sum}");
}

#[test]
fn the_sphere_image_centre_is_the_crossing_face_on_and_off_it_at_an_angle() {
    let d = Display::from_corners(
        DVec3::new(-1.0, -1.0, -1.0),
        DVec3::new(1.0, -1.0, -1.0),
        DVec3::new(-1.0, 1.0, -1.0),
        0.063,
        spidar_rt::display::Stereo::Mono,
    );
    // Face on: the image of a sphere straight ahead is a circle around the crossing.
    let (u, v) = sphere_image_centre(&d, DVec3::ZERO, DVec3::new(0.0, 0.0, -0.5), 0.1).unwrap();
    assert!((u - 1.0).abs() < 1e-12 && (v - 1.0).abs() < 1e-12);
    // At 45 degrees the image is an ellipse centred further out than the centre's crossing.
    let c = DVec3::new(0.5, 0.0, -0.5);
    let (u, _) = sphere_image_centre(&d, DVec3::ZERO, c, 0.1).unwrap();
    let (uc, _) = d.crossing(DVec3::ZERO, c).unwrap();
    assert!(u > uc + 0.01, "{u} vs {uc}");
}

/// The screen `place` tests put in front of the rig: off-centre and turned on all three axes.
fn placed_truth() -> Display {
    let f = spidar_rt::display::DisplayFile {
        screen: spidar_rt::display::ScreenFile::Centre {
            centre_m: [0.1, 0.0, -0.9],
            size_m: [1.8, 1.2],
            yaw_deg: 10.0,
            pitch_deg: -6.0,
            roll_deg: 2.0,
        },
        eye_separation_m: 0.063,
        stereo: spidar_rt::display::Stereo::Mono,
    };
    spidar_rt::display::validate(&f, super::rig().eye_m).unwrap()
}

/// A scripted person at the simulated rig places the screen on the calibration session's path
/// (`spidar calib screen --device sim`: the calibrating rt-loop holding the strings at minimum
/// tension, on the virtual clock): the right grip's centre held on each target, the ball touching
/// the screen (`off_m` moves the third target off the screen). `fault_at_s`: a run of failed
/// exchanges (a board that stops answering for 0.3 s) starts then; the loop's records are kept.
fn place_with_script(
    off_m: f64,
    aim_off_m: [DVec3; 5],
    fault_at_s: Option<f64>,
) -> anyhow::Result<(spidar_runtime::placement::Placed<Faulting>, Vec<spidar_rt::telemetry::TickRecord>)> {
    use spidar_runtime::placement::{place_screen, scripted_person, PlaceOptions};
    use spidar_runtime::session::{sim_device, SimOptions};
    let rig = super::rig();
    let truth = placed_truth();
    let mut aim = aim_off_m;
    aim[2] += truth.normal() * off_m;
    let scripts = scripted_person(&rig, &truth, aim);
    let dev = sim_device(&rig, scripts, &SimOptions { encoder_noise_counts: 0.5, ..SimOptions::default() })?;
    let lp = spidar_calib::ticks::VirtualLoop::start(dev, &rig, false)?;
    let fault_at = fault_at_s.map(|s| (s / rig.period_s) as u64);
    let records = std::rc::Rc::new(std::cell::RefCell::new(Vec::new()));
    let source = Faulting { lp, n: 0, fault_at, records: records.clone() };
    let opts = PlaceOptions { timeout_s: 60.0, ..PlaceOptions::default() };
    let placed = place_screen(source, &rig, &opts, &mut |_| {})?;
    let recs = records.take();
    Ok((placed, recs))
}

/// The calibrating loop on the simulated rig, its records kept, with a fault injected at a tick.
struct Faulting {
    lp: spidar_calib::ticks::VirtualLoop<spidar_device::sim::SimRig>,
    n: u64,
    fault_at: Option<u64>,
    records: std::rc::Rc<std::cell::RefCell<Vec<spidar_rt::telemetry::TickRecord>>>,
}

impl spidar_calib::ticks::TickSource for Faulting {
    fn next_record(&mut self) -> Result<spidar_rt::telemetry::TickRecord, spidar_calib::CalibError> {
        if Some(self.n) == self.fault_at {
            self.lp.device_mut().fail_next(300, spidar_device::DeviceError::Timeout { waited_us: 1000 });
        }
        self.n += 1;
        let r = self.lp.next_record()?;
        self.records.borrow_mut().push(r);
        Ok(r)
    }
    fn finish(&mut self) -> Result<(), spidar_calib::CalibError> {
        self.lp.finish()
    }
}

/// Where the scripted person must aim at each target for the grip to land on it: the first
/// session's misses, the other way.
fn corrected_aim(first: &spidar_calib::display::Placement) -> [DVec3; 5] {
    let truth = placed_truth();
    let r = super::rig().hands[1].grip_radius_m;
    let mut aim = [DVec3::ZERO; 5];
    for (k, &(a, b)) in spidar_calib::display::TARGETS.iter().enumerate() {
        aim[k] = spidar_runtime::placement::target_grip_m(&truth, (a, b), r) - first.grips_m[k];
    }
    aim
}

fn assert_within_5_mm(d: &Display) {
    let truth = placed_truth();
    for (name, got, want) in [
        ("lower left", d.lower_left_m, truth.lower_left_m),
        ("lower right", d.lower_right_m(), truth.lower_right_m()),
        ("upper left", d.upper_left_m(), truth.upper_left_m()),
    ] {
        let e = (got - want).length();
        assert!(e < 0.005, "the {name} corner is {:.2} mm from the truth", e * 1e3);
    }
}

/// Placing the screen (`spidar calib screen`'s path: the calibrating loop): the scripted
/// person's five targets give the screen's rectangle within 5 mm of the truth on the simulated
/// rig; a target held off the screen is refused, saying which.
///
/// The person aims by sight: the simulated arm holds the grip where its impedance and the strings'
/// pull balance, which outside a hand's anchor tetrahedron (where the minimum tensions cannot
/// cancel) is a few millimetres off the aim. The person sees the grip beside the target and aims
/// again that much the other way: the second session is the one placed.
#[test]
fn display_placement_finds_the_screen_within_5_mm_and_refuses_a_bad_one() {
    let (first, _) = place_with_script(0.0, [DVec3::ZERO; 5], None).unwrap();
    let aim = corrected_aim(&first.placement);
    let (placed, records) = place_with_script(0.0, aim, None).unwrap();
    let p = &placed.placement;
    eprintln!(
        "placement: the grips missed by up to {:.1} mm at first; placed: rms {:.2} mm, worst {:.2} mm (target {})",
        aim.iter().map(|a| a.length()).fold(0.0, f64::max) * 1e3,
        p.rms_m * 1e3,
        p.worst_m * 1e3,
        p.worst_target + 1
    );
    assert_within_5_mm(&p.display);
    // The loop held the strings throughout: calibrating, never active, minimum tension, no force.
    let rig = super::rig();
    for r in &records {
        assert_ne!(r.state, spidar_rt::Lifecycle::Active);
        for (h, hr) in rig.hands.iter().enumerate() {
            assert!(r.hands[h]
                .tensions_n
                .iter()
                .all(|&t| t >= hr.tension_min_n - 1e-9 && t <= hr.tension_max_n + 1e-9));
            assert_eq!(r.hands[h].commanded_n, DVec3::ZERO);
        }
    }
    assert_eq!(placed.source.lp.counters().faults, 0);
    let e = place_with_script(0.03, aim, None).err().expect("target 3 off the screen is refused").to_string();
    assert!(e.contains("target 3"), "{e}");
}

/// A fault while placing is the loop's: the board stops answering for 0.3 s while the grip
/// reaches for target 2; the calibrating loop goes safe (faulted: no force, strings taut, within
/// their limits), counts the fault and the failed exchanges, recovers by itself, and placement
/// leaves the ticks it did not take out and still finds the screen within 5 mm.
#[test]
fn display_placement_a_fault_is_the_loops_faded_counted_and_left_out() {
    let (first, _) = place_with_script(0.0, [DVec3::ZERO; 5], None).unwrap();
    let aim = corrected_aim(&first.placement);
    // Halfway through the reach from target 1 to target 2 (the scripted person's timing).
    let (truth, rig) = (placed_truth(), super::rig());
    let at = |k: usize| {
        spidar_runtime::placement::target_grip_m(
            &truth,
            spidar_calib::display::TARGETS[k],
            rig.hands[1].grip_radius_m,
        ) + aim[k]
    };
    let reach_s = |a: DVec3, b: DVec3| 0.3 + 2.0 * a.distance(b);
    let t_fault = 1.5 + reach_s(rig.hands[1].home_m, at(0)) + 1.8 + 0.5 * reach_s(at(0), at(1));
    let (placed, records) = place_with_script(0.0, aim, Some(t_fault)).unwrap();
    assert_within_5_mm(&placed.placement.display);
    let faulted: Vec<_> = records.iter().filter(|r| r.state == spidar_rt::Lifecycle::Faulted).collect();
    assert!(!faulted.is_empty(), "the run of failed exchanges faults the loop");
    for r in &faulted {
        for (h, hr) in rig.hands.iter().enumerate() {
            assert_eq!(r.hands[h].commanded_n, DVec3::ZERO, "no force while faulted");
            assert!(r.hands[h]
                .tensions_n
                .iter()
                .all(|&t| t >= hr.tension_min_n - 1e-9 && t <= hr.tension_max_n + 1e-9));
        }
    }
    let c = placed.source.lp.counters();
    assert_eq!(c.faults, 1, "{c:?}");
    assert!(c.device_errors >= 300, "{c:?}");
    assert!(placed.stats.faulted > 0 && placed.stats.late_or_bad >= 300, "{}", placed.stats);
    let last = records.last().unwrap();
    assert_ne!(last.state, spidar_rt::Lifecycle::Faulted, "the fault cleared by itself");
}

/// `spidar run --virtual --record PATH` of `seconds` on the boxing scene with the hold script, on
/// the rig file `rig_file` (attached to the rig's recording); returns the world's recording.
fn record_on(rig_file: &std::path::Path, path: &std::path::Path, seconds: f64) -> std::path::PathBuf {
    use spidar_runtime::recording::{create, session_info, start_world_recording};
    use spidar_runtime::session::{load_scripts, run_virtual, sim_device, SimOptions, VirtualOptions};
    let r = Rig::load(rig_file).unwrap();
    let dev = sim_device(&r, load_scripts("hold", &r, 1).unwrap(), &SimOptions::default()).unwrap();
    let info = session_info(Some(rig_file), "boxing", "hold", "Sim", 1, true).unwrap();
    let recorder = create(path, &info).unwrap();
    let scene = spidar_world::load("boxing").unwrap();
    let wpath = spidar_record::world::world_path(path);
    let (wrec, obs) =
        start_world_recording(&wpath, "boxing", &*scene, true, Some(recorder.start_unix_ns())).unwrap();
    let opts = VirtualOptions {
        seconds,
        stop: spidar_runtime::signals::Stop::detached(),
        progress: false,
        device: "Sim".into(),
        scene_name: "boxing".into(),
        script_name: "hold".into(),
        supervisor: None,
        recorder: Some(recorder),
        observers: vec![Box::new(obs)],
    };
    let sum = run_virtual(dev, &r, scene, opts).unwrap();
    assert!(sum.counters.active_ticks > 1000, "{sum}");
    let w = wrec.finish();
    assert_eq!((w.dropped, w.write_failed), (0, 0), "{w}");
    wpath
}

/// `GET path` from a view server at `url`: the JSON it answers.
fn get_json(url: &str, path: &str) -> Value {
    use std::io::{Read, Write};
    let host = url.trim_start_matches("http://").trim_end_matches('/');
    let mut c = std::net::TcpStream::connect(host).unwrap();
    write!(c, "GET {path} HTTP/1.0\r\nHost: {host}\r\nConnection: close\r\n\r\n").unwrap();
    let mut text = String::new();
    c.read_to_string(&mut text).unwrap();
    let body = &text[text.find("\r\n\r\n").expect("an HTTP answer") + 4..];
    serde_json::from_str(body).unwrap()
}

/// `spidar replay` keeps the screen: a session recorded on the rig file with the off-centre,
/// tilted screen, replayed into chromium, is drawn through that screen exactly as the live page
/// draws it (the same checks as `display_draws_the_rig_frame_through_the_screen_from_the_eye`, on
/// the replay's page: for both grips and the virtual human's head, for each eye in each stereo
/// format, the replayed frame's off-axis projection within 2 px of where the eye's ray crosses the
/// screen, as the live one's is). Without the screen the replay would draw a plain 70 degree
/// perspective, and every check would miss by far more.
#[test]
fn display_replay_draws_through_the_recorded_screen_as_the_live_view() {
    let _one = one_at_a_time();
    if !browser_here("display_replay_draws_through_the_recorded_screen_as_the_live_view") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("spidar-display-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rig_file = dir.join("rig.ron");
    std::fs::write(&rig_file, screen_rig_text()).unwrap();
    let world = record_on(&rig_file, &dir.join("screen.mcap"), 8.0);
    // The rig file goes away: the replay has only the recording.
    std::fs::remove_file(&rig_file).unwrap();
    let screen = spidar_runtime::replay_view::recorded_screen(&world).expect("the recorded screen");
    assert_eq!(screen, spidar_rt::status::rig_info(&screen_rig()).display);
    let o = spidar_runtime::replay_view::ReplayOptions {
        view: spidar_world::view::ViewOptions { addr: ([127, 0, 0, 1], 0).into(), ..Default::default() },
        from_s: None,
        speed: 1.0,
        play: true,
    };
    let replay = spidar_runtime::replay_view::Replay::start(&world, &o).unwrap();
    let url = replay.url().to_string();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let s = stop.clone();
    let thread =
        std::thread::spawn(move || replay.run(&|| s.load(std::sync::atomic::Ordering::Relaxed)).unwrap());
    let scene = get_json(&url, "/scene.json");
    let off: Vec<f64> =
        scene["link_offset_m"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
    let link_offset_m = DVec3::new(off[0], off[1], off[2]);
    let rig = screen_rig();
    node_script("display.mjs", &["screen", &url], |q| match q["ask"].as_str().unwrap() {
        "screen_pixels" => screen_pixels(&rig, link_offset_m, q),
        other => json!({"error": format!("unknown question {other}")}),
    });
    stop.store(true, std::sync::atomic::Ordering::Relaxed);
    thread.join().unwrap();
    let _ = std::fs::remove_dir_all(&dir);
}

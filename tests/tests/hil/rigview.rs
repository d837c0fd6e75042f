//! The live view's rig overlays in a browser (tests/browser/rigview.mjs), on `spidar run`'s path:
//! the simulated rig, the rt-loop and the child world process serving the view. The world's side
//! answers with the rig map's own maths: how many feasible cells each hand has, and which strings
//! are near for the grips the page shows.

use glam::DVec3;
use serde_json::{json, Value};
use spidar_rt::status::rig_info;
use spidar_world::view::rigview::{near_mask, workspace, NearStrings, WORKSPACE_STEP_M};

use super::rig;
use super::view::{browser_here, node_script, one_at_a_time, RunPath};

/// Seconds the scripted user holds both grips at home before moving the right one away.
const AT_HOME_S: f64 = 25.0;

/// Both grips at home for [`AT_HOME_S`], then the right one 10 cm right and 10 cm up, held.
fn script(home: [DVec3; 2]) -> String {
    let p = |v: DVec3| format!("({}, {}, {})", v.x, v.y, v.z);
    let apart = home[1] + DVec3::new(0.1, 0.1, 0.0);
    format!(
        "(kind: \"script\", version: 1, hands: (
            (segments: [Hold(at_m: {l}, for_s: 600.0)], repeat: false),
            (segments: [Hold(at_m: {r}, for_s: {AT_HOME_S}), Reach(to_m: {a}, duration_s: 1.0)], repeat: false),
        ))",
        l = p(home[0]),
        r = p(home[1]),
        a = p(apart),
    )
}

fn v3(v: &Value) -> DVec3 {
    let f = |i: usize| v[i].as_f64().unwrap_or(f64::NAN);
    DVec3::new(f(0), f(1), f(2))
}

/// The view's workspace volume is drawn where the map's feasible cells project and hidden by its
/// toggle; the strings within the rig's near distance of another hand's string are drawn
/// highlighted and the others not (grips at home), and none once the grips are apart.
#[test]
fn view_draws_the_rig_workspace_and_near_strings_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("view_draws_the_rig_workspace_and_near_strings_in_a_browser") {
        return;
    }
    let r = rig();
    let dir = std::env::temp_dir().join(format!("spidar-rigview-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("script.ron");
    std::fs::write(&file, script([r.hands[0].home_m, r.hands[1].home_m])).unwrap();
    let run = RunPath::start_on("walls", file.to_str().unwrap(), r.clone());
    let info = rig_info(&r);
    let offset = v3(&run.get("/scene.json")["link_offset_m"]);
    // The rig file's near distance and forearm (its `near_strings`), as the rig sends them.
    let near_m = r.near_strings.distance_m;
    let near = NearStrings::new(&info, offset);
    node_script("rigview.mjs", &[&run.url], |q| match q["ask"].as_str().unwrap_or("") {
        "check_workspace" => {
            for h in 0..2 {
                let want = workspace(&info, h, WORKSPACE_STEP_M).cells.len() as u64;
                assert_eq!(q["cells"][h].as_u64(), Some(want), "hand {h}'s feasible cells in the page");
            }
            assert_eq!(q["strings_near_m"].as_f64(), Some(near_m), "the near distance the page got");
            json!({"ok": true})
        }
        "near_mask" => {
            let grips = [0, 1].map(|h| Some(v3(&q["grips"][h])));
            json!({"mask": near_mask(&near.anchors_m, grips, near.near_m, &near.forearm)})
        }
        other => json!({"error": format!("unknown question {other}")}),
    });
    let said = run.said.clone();
    let sum = run.finish();
    let _ = std::fs::remove_dir_all(&dir);
    assert!(sum.clean_stop, "{sum}; the world said {:?}", said.lock().unwrap());
}

//! The recording commands as a user runs them: `spidar run --record ... --json` reports both
//! files (the rig's and the world's, also when a child world process wrote it), and `spidar plot`
//! draws every panel of a real recording, and still plots a file cut short, saying so.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::Value;

const BIN: &str = env!("CARGO_BIN_EXE_spidar");

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("spidar-recording-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `spidar args` in `dir`: whether it succeeded, its stdout and stderr.
fn spidar_any(dir: &Path, args: &[&str]) -> (bool, String, String) {
    let o = Command::new(BIN).args(args).current_dir(dir).output().expect("running spidar");
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    (o.status.success(), text(&o.stdout), text(&o.stderr))
}

/// Runs `spidar args` in `dir`; its stdout, after checking it succeeded.
fn spidar(dir: &Path, args: &[&str]) -> String {
    let (ok, out, err) = spidar_any(dir, args);
    assert!(ok, "spidar {args:?} failed:\n{out}\n{err}");
    out
}

/// The world recording's report in `run --json` is the file's: its path, its size, its steps.
fn check_world_report(dir: &Path, j: &Value, rig_file: &str, min_steps: u64) {
    let w = &j["world_recording"];
    let path = w["path"].as_str().expect("a world_recording with its path");
    assert_eq!(path, rig_file.replace(".mcap", ".world.mcap"), "{w}");
    let size = std::fs::metadata(dir.join(path)).unwrap().len();
    assert_eq!(w["bytes"].as_u64(), Some(size), "{w}");
    let steps = w["steps"].as_u64().unwrap();
    assert!(steps >= min_steps && w["messages"].as_u64().unwrap() > steps, "{w}");
    let nk = &w["not_kept"];
    assert_eq!(
        nk["total"].as_u64().unwrap(),
        nk["queue_dropped"].as_u64().unwrap() + nk["write_failed"].as_u64().unwrap(),
        "{w}"
    );
    assert!(w["error"].is_null(), "{w}");
    // The rig's own report is there too.
    assert_eq!(j["recording"]["path"], rig_file, "{j}");
    assert!(j["recording"]["ticks"].as_u64().unwrap() > 0, "{j}");
}

#[test]
fn run_json_reports_the_world_recording_as_well_as_the_rigs() {
    let dir = temp_dir("json");
    // The world in this process (the virtual clock): its recorder's own report.
    let out = spidar(&dir, &["run", "--virtual", "--seconds", "2", "--record", "v.mcap", "--json"]);
    let j: Value = serde_json::from_str(&out).unwrap();
    check_world_report(&dir, &j, "v.mcap", 600);
    assert_eq!(j["world_recording"]["not_kept"]["total"], 0, "the virtual clock waits for nothing: {j}");
    // The world in its child process (the default): read back from the file it wrote. (On a
    // loaded machine the rig may not become active in time, and the run then exits non-zero: its
    // JSON is printed all the same.)
    let args = ["run", "--seconds", "3", "--no-rt", "--no-view", "--record", "c.mcap", "--json"];
    let (_, out, err) = spidar_any(&dir, &args);
    let j: Value = serde_json::from_str(&out).unwrap_or_else(|e| panic!("{e}: {out}\n{err}"));
    check_world_report(&dir, &j, "c.mcap", 1);
}

/// The texts of an SVG's `<text>` elements, and the points of its data lines (polylines of more
/// than two points: axes and ticks have two).
fn svg(path: &Path) -> (Vec<String>, Vec<Vec<(f64, f64)>>) {
    let s = std::fs::read_to_string(path).unwrap();
    let texts = s
        .split("<text")
        .skip(1)
        .map(|t| {
            let body = &t[t.find('>').unwrap() + 1..];
            body[..body.find("</text>").unwrap()].trim().to_string()
        })
        .collect();
    let lines = s
        .split("<polyline")
        .skip(1)
        .filter_map(|p| {
            let pts = &p[p.find("points=\"").unwrap() + 8..];
            let pts: Vec<(f64, f64)> = pts[..pts.find('"').unwrap()]
                .split_whitespace()
                .map(|xy| {
                    let (x, y) = xy.split_once(',').unwrap();
                    (x.parse().unwrap(), y.parse().unwrap())
                })
                .collect();
            (pts.len() > 2).then_some(pts)
        })
        .collect();
    (texts, lines)
}

fn has(texts: &[String], start: &str) -> bool {
    texts.iter().any(|t| t.starts_with(start))
}

#[test]
fn plot_draws_every_panel_of_a_recorded_bout_and_plots_a_file_cut_short_with_a_note() {
    let dir = temp_dir("plot");
    spidar(&dir, &["run", "--virtual", "--seconds", "6", "--record", "bout.mcap", "--quiet"]);
    let out = spidar(&dir, &["plot", "bout.mcap"]);
    assert!(out.contains("wrote        bout.svg") && out.contains("world        bout.world.mcap"), "{out}");
    let (texts, lines) = svg(&dir.join("bout.svg"));
    // Every panel, with its series named.
    let ticks = texts.iter().find_map(|t| t.strip_prefix("bout.mcap: scene boxing, script box, ")).unwrap();
    let ticks: u64 = ticks.strip_suffix(" ticks").unwrap().parse().unwrap();
    assert!(ticks > 3000, "{ticks} ticks");
    for panel in [
        "force on each hand (peak per",
        "string tensions (peak per",
        &format!("wake-up lateness of {ticks} ticks"),
        "timeline: rig lifecycle",
        "the virtual human: hands",
    ] {
        assert!(has(&texts, panel), "no panel '{panel}' in {texts:?}");
    }
    for h in ["left", "right"] {
        assert!(texts.iter().any(|t| t == &format!("{h} hand")), "no {h} hand series");
        for s in 0..4 {
            assert!(texts.iter().any(|t| t == &format!("{h} string {s}")), "no {h} string {s} series");
        }
    }
    // Two forces and eight tensions, each a line over the session with data in it.
    assert_eq!(lines.len(), 10, "{} data lines", lines.len());
    for l in &lines {
        assert!(l.len() >= 100, "a series of {} points", l.len());
        let (lo, hi) = l.iter().fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
        assert!(hi - lo > 5.0, "a flat series ({lo}..{hi} px): no data drawn");
    }
    // The world's file alone: its panel alone.
    spidar(&dir, &["plot", "bout.world.mcap", "-o", "world.svg"]);
    let (wt, _) = svg(&dir.join("world.svg"));
    assert!(has(&wt, "the virtual human: hands") && !has(&wt, "force on each hand"), "{wt:?}");
    // Cut short (the session killed): it plots what is there and says so, on screen and in the SVG.
    let bytes = std::fs::read(dir.join("bout.mcap")).unwrap();
    std::fs::write(dir.join("cut.mcap"), &bytes[..bytes.len() * 3 / 5]).unwrap();
    let out = spidar(&dir, &["plot", "cut.mcap"]);
    assert!(out.contains("cut short") && out.contains("wrote        cut.svg"), "{out}");
    let (ct, cl) = svg(&dir.join("cut.svg"));
    let title = ct.iter().find(|t| t.starts_with("cut.mcap: ")).unwrap();
    assert!(title.contains("NOT COMPLETE: cut short; plotted up to t = "), "{title}");
    assert_eq!(cl.len(), 10, "every series still drawn");
    assert!(!has(&ct, "the virtual human"), "no world file next to cut.mcap: no behaviour panel");
}

//! `spidar study reactions` with a scripted participant in a real browser (Debian's chromium
//! through puppeteer-core, `tests/browser/study.mjs`): the study as the command runs it (clips
//! made on the path of `spidar run`, the page served, answers to the CSV, the confusion matrix
//! printed), for one participant.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::channel;
use std::sync::Arc;

use serde_json::{json, Value};
use spidar_lab::eval::TARGETS;
use spidar_lab::study::{make_clips, order_for, read_answers, ClipOptions};
use spidar_lab::study_page::{study_reactions, StudyArgs};

use super::view::{browser_here, node_script, one_at_a_time};

/// Stops the study's server however the test ends.
struct StopOnDrop(Arc<AtomicBool>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

#[test]
fn study_page_shows_every_clip_once_in_random_order_and_keeps_every_answer_in_a_browser() {
    let _one = one_at_a_time();
    if !browser_here("study_page_shows_every_clip_once_in_random_order_and_keeps_every_answer_in_a_browser") {
        return;
    }
    let dir = std::env::temp_dir().join(format!("spidar-study-hil-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("answers.csv");
    let _ = std::fs::remove_file(&out);
    let seed = 5;
    let args = StudyArgs {
        out: out.clone(),
        trials: 1,
        seed,
        participants: Some(1),
        view: Some("127.0.0.1:0".into()),
    };
    let stop = Arc::new(AtomicBool::new(false));
    let _stop = StopOnDrop(stop.clone());
    let (said_tx, said) = channel::<String>();
    let study = std::thread::spawn(move || {
        study_reactions(&args, &|| stop.load(Ordering::Relaxed), |m| {
            let _ = said_tx.send(m.to_string());
        })
        .map(|t| t.to_string())
    });
    let url = loop {
        let m = said.recv().expect("the study ended before it served its page");
        if let Some(u) = m.split_whitespace().find(|w| w.starts_with("http://")) {
            break u.to_string();
        }
    };
    let mut subject = Value::Null;
    node_script("study.mjs", &[&url], |q| match q["ask"].as_str() {
        Some("subject") => {
            subject = q.clone();
            json!({})
        }
        other => panic!("the study test asked {other:?}"),
    });
    let printed = study.join().unwrap().unwrap();

    // The clips as the study made them (the same seed makes the same clips).
    let clips = make_clips(&ClipOptions { trials: 1, seed, ..Default::default() }, |_, _| {}).unwrap();
    let n = clips.clips.len();
    assert_eq!(n, 8, "one straight per target and condition");
    let truth = |id: u64| clips.clips.iter().find(|c| c.id as u64 == id).unwrap();

    // Every clip shown once, in the participant's own order, which is not the clips' order.
    let shown: Vec<u64> =
        subject["shown"].as_array().unwrap().iter().map(|s| s["clip"].as_u64().unwrap()).collect();
    let want: Vec<u64> = order_for("P07", seed, n).iter().map(|&i| clips.clips[i].id as u64).collect();
    assert_eq!(shown, want, "the clips shown, in order");
    let mut sorted = shown.clone();
    sorted.sort_unstable();
    assert_eq!(sorted, (1..=n as u64).collect::<Vec<_>>(), "every clip once");
    assert_ne!(shown, sorted, "a shuffled order");

    // The CSV has every answer the participant gave, with the clip's condition and target.
    let rows = read_answers(&out).unwrap();
    let given = subject["answers"].as_array().unwrap();
    assert_eq!(rows.len(), n);
    for (row, g) in rows.iter().zip(given) {
        let clip = truth(g["clip"].as_u64().unwrap());
        assert_eq!(row.participant, "P07");
        assert_eq!(row.clip, clip.id);
        assert_eq!((row.active, row.target), (clip.active, clip.target), "clip {}", clip.id);
        assert_eq!(row.answer as u64, g["answer"].as_u64().unwrap());
        let rt = g["response_s"].as_f64().unwrap();
        assert!((row.response_s - rt).abs() < 1e-3 && rt > 0.0 && rt < 30.0, "{} vs {rt}", row.response_s);
    }

    // The printed matrix is the answers' rates, per condition.
    for (m, cond) in ["active", "passive"].into_iter().enumerate() {
        let mut counts = [[0usize; 4]; 4];
        for g in given {
            let clip = truth(g["clip"].as_u64().unwrap());
            if usize::from(!clip.active) == m {
                counts[clip.target][g["answer"].as_u64().unwrap() as usize] += 1;
            }
        }
        let block = &printed[printed.find(&format!("{cond} reactions")).unwrap()..];
        for (t, name) in TARGETS.iter().enumerate() {
            let line = block.lines().find(|l| l.trim_start().starts_with(name)).unwrap();
            let rates: Vec<f64> = line
                .split('|')
                .take(4)
                .map(|p| p.split_whitespace().last().unwrap().parse().unwrap())
                .collect();
            let total: usize = counts[t].iter().sum();
            for a in 0..4 {
                let want = counts[t][a] as f64 / total.max(1) as f64;
                assert!(
                    (rates[a] - want).abs() < 0.006,
                    "{cond}, {name}, answer {a}: printed {}, {want}\n{printed}",
                    rates[a]
                );
            }
        }
        let right: usize = (0..4).map(|t| counts[t][t]).sum();
        let total = format!("total correct rate {:.2}", right as f64 / 4.0);
        assert!(block.contains(&total), "{cond}: {total}\n{printed}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

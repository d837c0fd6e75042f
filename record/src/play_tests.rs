//! Tests of playing a world recording into the view: the frames kept are the live view's, a seek
//! finds the frame at any time through the chunk index (the summary's, or the one built from the
//! chunks of a file cut short), and the player moves at its speed, pauses and stops at the end.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use crate::cdr;
use crate::foxglove::FrameTransforms;
use crate::play::{Indexed, Player, ViewTrack};
use crate::reader::{self, Ending, Flow, Msg};
use crate::world::*;
use crate::world_tests::{record_scene, temp};

/// Every view frame of a file, read front to back by the plain reader, and every step's poses
/// (`/world/tf`), by time.
struct Truth {
    frames: Vec<ViewFrameMsg>,
    tf: Vec<(f64, FrameTransforms)>,
}

fn truth(path: &Path) -> Truth {
    let (mut frames, mut tf) = (Vec::new(), Vec::new());
    let mut t_step = 0.0;
    reader::read(path, |_, m| {
        if let Msg::Other { channel, data, .. } = m {
            match channel.topic.as_str() {
                TOPIC_VIEW => frames.push(cdr::decode::<ViewFrameMsg>(data).unwrap()),
                TOPIC_STEP => t_step = cdr::decode::<WorldStep>(data).unwrap().t_s,
                TOPIC_TF => tf.push((t_step, cdr::decode::<FrameTransforms>(data).unwrap())),
                _ => {}
            }
        }
        Ok(Flow::Continue)
    })
    .unwrap();
    Truth { frames, tf }
}

impl Truth {
    /// The frame showing at `t`: the last at or before it.
    fn at(&self, t: f64) -> &ViewFrameMsg {
        self.frames.iter().rev().find(|f| f.t_s <= t).unwrap_or(&self.frames[0])
    }
}

/// A boxing recording of 2400 steps (7.2 s, several chunks), made once.
fn boxing() -> &'static (PathBuf, Truth) {
    static F: OnceLock<(PathBuf, Truth)> = OnceLock::new();
    F.get_or_init(|| {
        let p = temp("play.world.mcap");
        let (_, _, rep) = record_scene("boxing", &p, 2400);
        assert_eq!((rep.steps, rep.dropped, rep.error.clone()), (2400, 0, None), "{rep}");
        let t = truth(&p);
        (p, t)
    })
}

#[test]
fn a_world_recording_keeps_the_frames_the_live_view_drew() {
    let (p, truth) = boxing();
    let d: serde_json::Value = {
        let r = reader::read(p, |_, _| Ok(Flow::Stop)).unwrap();
        serde_json::from_str(&r.attachment_text(VIEW_ATTACHMENT).expect("the view's description")).unwrap()
    };
    assert_eq!((d["type"].as_str(), d["name"].as_str()), (Some("scene"), Some("boxing")));
    let look = spidar_world::load("boxing").unwrap().look();
    let layout = spidar_world::view::Layout::for_look(&look);
    assert_eq!(d["layout"]["id"].as_u64(), Some(layout.id as u64));
    // One frame per sixtieth of a second of scene time (every sixth 3 ms step).
    assert_eq!(truth.frames.len(), 400, "2400 steps of 3 ms at 60 frames a second");
    for w in truth.frames.windows(2) {
        assert!((w[1].t_s - w[0].t_s - 0.018).abs() < 1e-9, "{} then {}", w[0].t_s, w[1].t_s);
        assert_eq!(w[1].frame[2].to_bits(), w[0].frame[2].to_bits() + 1, "consecutive frame numbers");
    }
    let globals_at = d["layout"]["globals_at"].as_u64().unwrap() as usize;
    for f in &truth.frames {
        assert_eq!(f.frame[0].to_bits(), spidar_world::view::MAGIC);
        assert_eq!(f.frame[1].to_bits(), layout.id);
        assert_eq!(f.frame[globals_at], f.t_s as f32, "the frame's time");
        // Every moving shape where the step's own transforms put it.
        let (_, tf) = truth.tf.iter().find(|(t, _)| *t == f.t_s).expect("the frame's step");
        for k in 0..layout.shapes {
            let s = &f.frame[layout.shapes_at + 7 * k..];
            let x = &tf.transforms[k + 2];
            assert_eq!(
                [s[0], s[1], s[2]],
                [x.translation.x as f32, x.translation.y as f32, x.translation.z as f32],
                "shape {k} at t = {}",
                f.t_s
            );
        }
        // The heads-up display's numbers as the world had them.
        let st = f.status();
        let r = st.rig.expect("the rig's status");
        assert_eq!((r.state, r.tensions_n[1][3]), (spidar_msg::RigState::Active, 8.0));
        assert_eq!(r.tick % 3, 0);
        let g = f.rig_info().expect("the rig's geometry");
        assert!(g.anchors_m[1][3].length() > 0.1 && g.period_s == 0.001, "{g:?}");
        assert_eq!(st.t_s, f.t_s);
    }
    let last = truth.frames.last().unwrap().status();
    assert!(last.steps >= 2395 && last.counters[..6].iter().all(|c| c.is_finite()), "{last:?}");
}

/// The frames at times across the track, with the truth's frame at each.
fn check_seeks(track: &ViewTrack, truth: &Truth) -> usize {
    let (a, b) = (track.first_t_s, track.last_t_s);
    let mut n = 0;
    for k in 0..=40 {
        let t = a - 0.5 + (b - a + 1.0) * k as f64 / 40.0;
        let got = track.frame_at(t).unwrap();
        assert_eq!(&got, truth.at(t), "the frame at t = {t}");
        n += 1;
    }
    // Exactly at a frame's time, and just before it.
    for f in truth.frames.iter().step_by(37) {
        assert_eq!(track.frame_at(f.t_s).unwrap().t_s, f.t_s);
        assert_eq!(&track.frame_at(f.t_s - 1e-6).unwrap(), truth.at(f.t_s - 1e-6));
        n += 2;
    }
    n
}

#[test]
fn a_seek_finds_the_frame_at_any_time_through_the_summarys_chunk_index() {
    let (p, truth) = boxing();
    let track = ViewTrack::open(p).unwrap();
    assert_eq!((track.indexed, track.ending.clone()), (Indexed::Summary, Ending::Complete));
    assert!(track.chunks() >= 4, "{} chunks: the seeks cross chunks", track.chunks());
    assert_eq!(track.first_t_s, truth.frames[0].t_s);
    assert_eq!(track.last_t_s, truth.frames.last().unwrap().t_s);
    assert!(check_seeks(&track, truth) > 50);
}

#[test]
fn a_file_cut_short_is_indexed_from_its_chunks_and_plays_up_to_where_it_ends() {
    let (p, _) = boxing();
    let cut = temp("play-cut.world.mcap");
    let bytes = std::fs::read(p).unwrap();
    std::fs::write(&cut, &bytes[..bytes.len() * 3 / 5]).unwrap();
    let truth = truth(&cut);
    assert!(truth.frames.len() > 50 && truth.frames.len() < 300, "{} frames left", truth.frames.len());
    let track = ViewTrack::open(&cut).unwrap();
    assert_eq!(track.indexed, Indexed::ChunkHeaders);
    assert!(matches!(track.ending, Ending::CutShort { .. }), "{:?}", track.ending);
    assert_eq!(track.last_t_s, truth.frames.last().unwrap().t_s, "the last frame of the last whole chunk");
    check_seeks(&track, &truth);
    // Played to its end, it stops there.
    let mut pl = Player::new(track).unwrap();
    pl.set_speed(16.0);
    pl.play(true).unwrap();
    let mut n = 0;
    while pl.playing() {
        pl.advance(0.05).unwrap();
        n += 1;
        assert!(n < 1000, "it never stopped");
    }
    assert!(pl.at_end() && pl.frame() == truth.frames.last().unwrap());
}

#[test]
fn the_player_plays_at_its_speed_pauses_and_seeks() {
    let (p, truth) = boxing();
    let mut pl = Player::new(ViewTrack::open(p).unwrap()).unwrap();
    let t0 = pl.t_s();
    assert_eq!(pl.frame(), &truth.frames[0]);
    // Paused: time stands.
    assert!(pl.advance(0.5).unwrap().is_none());
    assert_eq!(pl.t_s(), t0);
    // At 2x, 0.1 s of wall time is 0.2 s of the recording; every frame shown is the one due.
    pl.set_speed(2.0);
    pl.play(true).unwrap();
    for k in 1..=10 {
        let shown = pl.advance(0.1).unwrap().cloned();
        let t = pl.t_s();
        assert!((t - (t0 + 0.2 * k as f64)).abs() < 1e-9, "position {t}");
        assert_eq!(shown.as_ref(), Some(truth.at(t)), "the frame due at {t}");
    }
    // A quarter of the speed: a quarter of the way.
    pl.set_speed(0.25);
    let before = pl.t_s();
    pl.advance(0.4).unwrap();
    assert!((pl.t_s() - before - 0.1).abs() < 1e-9);
    pl.play(false).unwrap();
    let paused_at = pl.t_s();
    assert!(pl.advance(1.0).unwrap().is_none() && pl.t_s() == paused_at, "paused: no time passes");
    // Seeks back and forth, then plays on from there.
    let target = truth.frames[250].t_s + 0.005;
    assert_eq!(pl.seek(target).unwrap(), &truth.frames[250]);
    pl.seek(truth.frames[10].t_s).unwrap();
    assert_eq!(pl.frame(), &truth.frames[10]);
    pl.set_speed(1.0);
    pl.play(true).unwrap();
    assert_eq!(pl.advance(0.02).unwrap(), Some(&truth.frames[11]));
    // Seeking past the end stops at the last frame.
    pl.seek(1e9).unwrap();
    assert!(pl.at_end() && pl.frame() == truth.frames.last().unwrap());
    assert!(pl.advance(0.1).unwrap().is_none() && !pl.playing(), "nothing after the last frame");
}

#[test]
fn a_rig_recording_or_a_recording_without_frames_says_what_to_open() {
    let (p, _) = boxing();
    // The rig's file of a session: told to take the world's.
    let rig = temp("play-rig.mcap");
    let info = crate::writer::SessionInfo {
        rig_origin: "test".into(),
        rig_text: spidar_rt::rig::DEFAULT_RIG_RON.into(),
        ..Default::default()
    };
    let r = crate::writer::Recorder::create(&rig, &info).unwrap();
    r.finish(&Default::default());
    let e = ViewTrack::open(&rig).err().unwrap().to_string();
    assert!(e.contains("rig recording") && e.contains(".world.mcap"), "{e}");
    // A world file cut short before its first frame.
    let cut = temp("play-empty.world.mcap");
    let bytes = std::fs::read(p).unwrap();
    std::fs::write(&cut, &bytes[..4000]).unwrap();
    let e = ViewTrack::open(&cut).err().unwrap().to_string();
    assert!(e.contains("no view frame"), "{e}");
}

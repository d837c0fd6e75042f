//! `spidar bench replay FILE`: what playing a recording into the view costs. How long opening a
//! world recording takes (its chunk index), how long a seek to a random time takes (the frame at
//! that time found and decoded), and the frame rate the replay serves to WebSocket viewers that
//! read every frame, playing at 1x (the path of `spidar replay`: the same player, server and
//! threads; viewers are plain WebSocket clients, not browsers).

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use rand::{Rng, SeedableRng};
use spidar_record::play::{Indexed, Player, ViewTrack};
use spidar_world::view::ViewOptions;

use spidar_runtime::replay_view::{Replay, ReplayOptions};

pub struct ReplayBenchOptions {
    /// The world recording (or the rig's, with the world's next to it).
    pub file: PathBuf,
    pub seeks: usize,
    pub viewers: usize,
    /// Seconds of playing at 1x to the viewers.
    pub seconds: f64,
}

pub struct ReplayBenchReport {
    pub file: PathBuf,
    pub bytes: u64,
    pub span_s: f64,
    pub chunks: usize,
    pub indexed: Indexed,
    pub open_s: f64,
    /// Seek times (s), sorted.
    pub seeks: Vec<f64>,
    pub viewers: usize,
    pub played_s: f64,
    /// Frames the replay published, and each viewer received, per second.
    pub published_hz: f64,
    pub received_hz: Vec<f64>,
}

fn q(v: &[f64], p: f64) -> f64 {
    v.get(((v.len() as f64 - 1.0) * p).round() as usize).copied().unwrap_or(f64::NAN)
}

impl std::fmt::Display for ReplayBenchReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let ms = |s: f64| s * 1e3;
        writeln!(
            f,
            "spidar bench replay {}: {:.1} MB, {:.1} s of frames in {} chunks",
            self.file.display(),
            self.bytes as f64 / 1e6,
            self.span_s,
            self.chunks
        )?;
        writeln!(
            f,
            "  open         {:.1} ms (the chunk index from {})",
            ms(self.open_s),
            match self.indexed {
                Indexed::Summary => "the summary",
                Indexed::ChunkHeaders => "the chunks' headers: no summary",
            }
        )?;
        writeln!(
            f,
            "  seek         {} to random times: median {:.2} ms, p90 {:.2} ms, max {:.2} ms",
            self.seeks.len(),
            ms(q(&self.seeks, 0.5)),
            ms(q(&self.seeks, 0.9)),
            ms(q(&self.seeks, 1.0))
        )?;
        let rx: Vec<String> = self.received_hz.iter().map(|r| format!("{r:.1}")).collect();
        write!(
            f,
            "  playing 1x   {:.1} s to {} viewer(s): {:.1} frames/s published, received per viewer [{}] frames/s",
            self.played_s,
            self.viewers,
            self.published_hz,
            rx.join(", ")
        )
    }
}

pub fn bench_replay(o: &ReplayBenchOptions) -> anyhow::Result<ReplayBenchReport> {
    let file = if o.file.to_string_lossy().ends_with(".world.mcap") {
        o.file.clone()
    } else {
        spidar_record::world::world_path(&o.file)
    };
    let bytes = std::fs::metadata(&file)?.len();
    let t0 = Instant::now();
    let track = ViewTrack::open(&file)?;
    let open_s = t0.elapsed().as_secs_f64();
    let (first, last, chunks, indexed) = (track.first_t_s, track.last_t_s, track.chunks(), track.indexed);
    let mut player = Player::new(track)?;
    let mut rng = rand_pcg::Pcg64::seed_from_u64(1);
    let mut seeks = Vec::with_capacity(o.seeks);
    for _ in 0..o.seeks {
        let t = rng.random_range(first..=last.max(first));
        let s = Instant::now();
        player.seek(t)?;
        seeks.push(s.elapsed().as_secs_f64());
    }
    seeks.sort_by(f64::total_cmp);
    drop(player);

    // Playing to viewers that read every frame.
    let view =
        ViewOptions { addr: ([127, 0, 0, 1], 0).into(), max_viewers: o.viewers.max(1), ..Default::default() };
    let mut replay = Replay::start(&file, &ReplayOptions { view, from_s: None, speed: 1.0, play: false })?;
    let stop = Arc::new(AtomicBool::new(false));
    let counts: Vec<Arc<AtomicU64>> = (0..o.viewers).map(|_| Arc::new(AtomicU64::new(0))).collect();
    let threads: Vec<_> = counts
        .iter()
        .map(|c| {
            let (c, stop, url) = (c.clone(), stop.clone(), replay.ws_url().to_string());
            std::thread::spawn(move || -> anyhow::Result<()> {
                let stream = std::net::TcpStream::connect(url.trim_start_matches("ws://"))?;
                stream.set_read_timeout(Some(Duration::from_millis(100)))?;
                let (mut ws, _) = tungstenite::client(format!("{url}/"), stream)?;
                while !stop.load(Ordering::Relaxed) {
                    match ws.read() {
                        Ok(tungstenite::Message::Binary(_)) => {
                            c.fetch_add(1, Ordering::Relaxed);
                        }
                        Ok(_) => {}
                        Err(tungstenite::Error::Io(e))
                            if matches!(
                                e.kind(),
                                std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                            ) => {}
                        Err(e) => return Err(e.into()),
                    }
                }
                Ok(())
            })
        })
        .collect();
    let handle = replay.handle();
    let until = Instant::now() + Duration::from_secs(30);
    while handle.counters().viewers.load(Ordering::Relaxed) < o.viewers {
        anyhow::ensure!(Instant::now() < until, "the viewers did not connect");
        std::thread::sleep(Duration::from_millis(10));
    }
    // Play from the start (seeking back whenever the end comes), counting over the span.
    replay.command(r#"{"cmd":"play"}"#)?;
    let start = Instant::now();
    let (pub0, rx0): (u64, Vec<u64>) = (
        handle.counters().frames_published.load(Ordering::Relaxed),
        counts.iter().map(|c| c.load(Ordering::Relaxed)).collect(),
    );
    while start.elapsed().as_secs_f64() < o.seconds {
        replay.turn()?;
        if replay.player().at_end() {
            replay.command(r#"{"cmd":"play"}"#)?;
        }
        std::thread::sleep(Duration::from_millis(4));
    }
    let played_s = start.elapsed().as_secs_f64();
    let published_hz = (handle.counters().frames_published.load(Ordering::Relaxed) - pub0) as f64 / played_s;
    let received_hz =
        counts.iter().zip(rx0).map(|(c, r0)| (c.load(Ordering::Relaxed) - r0) as f64 / played_s).collect();
    stop.store(true, Ordering::Relaxed);
    drop(replay);
    for t in threads {
        let _ = t.join();
    }
    Ok(ReplayBenchReport {
        file,
        bytes,
        span_s: last - first,
        chunks,
        indexed,
        open_s,
        seeks,
        viewers: o.viewers,
        played_s,
        published_hz,
        received_hz,
    })
}

//! `spidar eval blows`: what the user's hands feel when the virtual human lands a blow on the
//! avatar, measured on the path of `spidar run` (a scripted user boxing through the simulated
//! rig, the rt-loop and the boxing world, in-process on the virtual clock, as [`Bout`] runs).
//!
//! The user throws the `box` script at an active virtual human, which attacks when it is idle.
//! For every blow the world reports (`ContactModel::blow`, a new `seq`), from the first tick that
//! rendered a model carrying it, over [`WINDOW_S`]: the blow's own force at the hands (the
//! loop's record `blow_n`: its push and burst as the rig applied them, after the gain, the clamp
//! and the allocation scaled the whole force), its peak and its impulse along the blow (per hand,
//! the mean of both); the peak of the whole force the rig applied to a hand (the avatar hands' own
//! contacts included: what the user's hands get); and the loop's counters: blows felt, the
//! bursts' work on the hands (their energy), bursts cut by their budget, ticks clamped.
//!
//! Must never: be used as a timed test, or read anything but what the rig applied and counted.

use std::fmt;

use glam::DVec3;
use spidar_rt::blow::BlowParams;
use spidar_rt::Rig;
use spidar_runtime::scripts::{box_plan, PlanOptions};
use spidar_sim::boxer::BoxerParams;

use crate::eval::{Bout, PATH};

/// How long after a blow arrives its force is measured (s): the burst (60 ms) and the push.
pub const WINDOW_S: f64 = 0.15;

/// Impact speed bins (m/s): lower edges; the last is open. The virtual human's fist mostly
/// lands at 0.2-1.8 m/s (its reach slows toward its target).
pub const SPEED_BINS: [f64; 5] = [0.0, 0.5, 1.0, 1.5, 2.0];

/// One landed blow and what the user's hands felt of it.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct FeltBlow {
    pub seq: u64,
    pub t_s: f64,
    pub speed_m_per_s: f64,
    pub momentum_n_s: f64,
    /// Largest force the rig applied to either hand in the window, all of it (N).
    pub peak_n: f64,
    /// Largest force of the blow itself on either hand (N), and its impulse along the blow over
    /// the window per hand (mean of both, N s).
    pub blow_peak_n: f64,
    pub blow_impulse_n_s: f64,
    /// Work the burst did on the hands, both hands, over its window (J), from the loop's counter.
    pub burst_energy_j: f64,
}

/// One speed bin's blows.
#[derive(Clone, Copy, Debug, Default, serde::Serialize)]
pub struct Bin {
    pub from_m_per_s: f64,
    pub to_m_per_s: f64,
    pub blows: usize,
    pub peak_n: f64,
    pub blow_peak_n: f64,
    pub blow_impulse_n_s: f64,
    pub burst_energy_mj: f64,
}

/// What `spidar eval blows` measured.
#[derive(Debug, serde::Serialize)]
pub struct BlowsReport {
    pub seconds: f64,
    pub seed: u64,
    pub path: &'static str,
    pub blows: Vec<FeltBlow>,
    pub bins: Vec<Bin>,
    /// The loop's counters at the end, per hand.
    pub blows_felt: [u64; 2],
    pub burst_energy_uj: [u64; 2],
    pub burst_cut_ticks: [u64; 2],
    pub push_limited_ticks: [u64; 2],
    pub clamped_ticks: [u64; 2],
    /// Largest force the rig applied to a hand during the whole bout, and its limit (N).
    pub max_force_n: f64,
    pub force_limit_n: f64,
    /// The burst's energy bound per blow per hand (J).
    pub burst_budget_j: f64,
    pub status: String,
}

/// A blow being measured: its start tick and running figures.
struct Open {
    blow: FeltBlow,
    dir: DVec3,
    started_tick: u64,
    burst_uj0: u64,
}

/// Runs `seconds` of the `box` script against the default (active) virtual human and measures
/// every landed blow.
pub fn eval_blows(seconds: f64, seed: u64, mut progress: impl FnMut(f64)) -> anyhow::Result<BlowsReport> {
    let rig = Rig::default_rig();
    let params = BoxerParams::default();
    let opts = PlanOptions { punches: (seconds as usize).max(1), ..Default::default() };
    let plan = box_plan(&rig, &params, seed, &opts)?;
    let mut b = Bout::new(params, plan.scripts, seed)?;
    let window = (WINDOW_S / rig.period_s).round() as u64;
    let ticks = (seconds / rig.period_s).round() as u64;
    let (mut blows, mut open) = (Vec::new(), None::<Open>);
    let (mut seen, mut max_force) = (0u64, 0.0f64);
    for i in 0..ticks {
        let (rec, _) = b.tick();
        for h in &rec.hands {
            max_force = max_force.max(h.output_n.length());
        }
        let core = b.v.rt.core();
        let burst_uj: u64 = core.counters().blow_burst_uj.iter().sum();
        if let Some(m) = core.contact_model() {
            if m.blow.seq > seen && rec.gain > 0.0 {
                seen = m.blow.seq;
                if let Some(o) = open.take() {
                    blows.push(close(o, burst_uj));
                }
                open = Some(Open {
                    blow: FeltBlow {
                        seq: m.blow.seq,
                        t_s: b.script_t_s(),
                        speed_m_per_s: m.blow.speed_m_per_s,
                        momentum_n_s: m.blow.momentum_n_s,
                        peak_n: 0.0,
                        blow_peak_n: 0.0,
                        blow_impulse_n_s: 0.0,
                        burst_energy_j: 0.0,
                    },
                    dir: rig.rig_to_world.vector_to_rig(m.blow.dir),
                    started_tick: rec.tick,
                    burst_uj0: burst_uj,
                });
            }
        }
        if let Some(o) = open.as_mut() {
            for h in &rec.hands {
                o.blow.peak_n = o.blow.peak_n.max(h.output_n.length());
                o.blow.blow_peak_n = o.blow.blow_peak_n.max(h.blow_n.length());
                o.blow.blow_impulse_n_s += h.blow_n.dot(o.dir) * rig.period_s / 2.0;
            }
            if rec.tick >= o.started_tick + window {
                blows.push(close(open.take().expect("open"), burst_uj));
            }
        }
        if i % 1000 == 0 {
            progress(i as f64 * rig.period_s);
        }
    }
    let c = *b.v.rt.core().counters();
    if let Some(o) = open.take() {
        blows.push(close(o, c.blow_burst_uj.iter().sum()));
    }
    let p = BlowParams::default();
    Ok(BlowsReport {
        seconds,
        seed,
        path: PATH,
        bins: bins(&blows),
        blows,
        blows_felt: c.blows_felt,
        burst_energy_uj: c.blow_burst_uj,
        burst_cut_ticks: c.blow_burst_cut,
        push_limited_ticks: c.blow_push_limited,
        clamped_ticks: c.clamped,
        max_force_n: max_force,
        force_limit_n: rig.hands[0].force_limit_n.min(rig.hands[1].force_limit_n),
        burst_budget_j: p.burst_budget_j,
        status: b.scene.status_text(),
    })
}

fn close(mut o: Open, burst_uj: u64) -> FeltBlow {
    o.blow.burst_energy_j = burst_uj.saturating_sub(o.burst_uj0) as f64 * 1e-6;
    o.blow
}

/// The blows by impact speed: count and mean figures per bin.
pub fn bins(blows: &[FeltBlow]) -> Vec<Bin> {
    let mut out: Vec<Bin> = SPEED_BINS
        .iter()
        .enumerate()
        .map(|(i, &from)| Bin {
            from_m_per_s: from,
            to_m_per_s: SPEED_BINS.get(i + 1).copied().unwrap_or(f64::INFINITY),
            ..Default::default()
        })
        .collect();
    for b in blows {
        let Some(bin) = out.iter_mut().rev().find(|x| b.speed_m_per_s >= x.from_m_per_s) else { continue };
        bin.blows += 1;
        bin.peak_n += b.peak_n;
        bin.blow_peak_n += b.blow_peak_n;
        bin.blow_impulse_n_s += b.blow_impulse_n_s;
        bin.burst_energy_mj += b.burst_energy_j * 1e3;
    }
    for bin in &mut out {
        let n = bin.blows.max(1) as f64;
        bin.peak_n /= n;
        bin.blow_peak_n /= n;
        bin.blow_impulse_n_s /= n;
        bin.burst_energy_mj /= n;
    }
    out
}

impl fmt::Display for BlowsReport {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        writeln!(f, "measured on {}", self.path)?;
        writeln!(
            f,
            "{} s of the box script against the active virtual human (seed {}): {} blows landed on the avatar",
            self.seconds,
            self.seed,
            self.blows.len()
        )?;
        writeln!(
            f,
            "per blow, over {:.0} ms from the first tick that rendered it (means per bin):",
            WINDOW_S * 1e3
        )?;
        writeln!(
            f,
            "  impact speed   blows  blow peak (N)  blow impulse (N s)  burst energy (mJ)  all forces peak (N)"
        )?;
        for b in &self.bins {
            let to = if b.to_m_per_s.is_finite() { format!("{:.1}", b.to_m_per_s) } else { "   ".into() };
            writeln!(
                f,
                "  {:>3.1}-{:<3} m/s    {:>5}  {:>13.2}  {:>18.3}  {:>17.2}  {:>19.2}",
                b.from_m_per_s, to, b.blows, b.blow_peak_n, b.blow_impulse_n_s, b.burst_energy_mj, b.peak_n
            )?;
        }
        writeln!(
            f,
            "loop counters (left/right): blows felt {}/{}, burst energy {:.1}/{:.1} mJ (bound {:.0} mJ per blow and hand), bursts cut {}/{} ticks, pushes limited {}/{} ticks, clamped {}/{} ticks",
            self.blows_felt[0],
            self.blows_felt[1],
            self.burst_energy_uj[0] as f64 * 1e-3,
            self.burst_energy_uj[1] as f64 * 1e-3,
            self.burst_budget_j * 1e3,
            self.burst_cut_ticks[0],
            self.burst_cut_ticks[1],
            self.push_limited_ticks[0],
            self.push_limited_ticks[1],
            self.clamped_ticks[0],
            self.clamped_ticks[1],
        )?;
        writeln!(
            f,
            "largest force on a hand {:.3} N (rig limit {:.1} N)",
            self.max_force_n, self.force_limit_n
        )?;
        write!(f, "scene: {}", self.status)
    }
}

//! The Z-width sweep (`spidar bench zwidth`): a grid of wall stiffness K (log-spaced) and damping
//! B, bouts ([`crate::zwidth`]) along each axis at home and off-centre, at each loop rate; the
//! boundary per B; the shipped scenes' contacts run as bouts of their own; and the report.
//!
//! Must never: report a boundary the grid did not show (a K is "passive" at a B only when every
//! smaller K of the grid was passive there too, in every case), or check a scene against anything
//! but bouts run at that scene's own stiffness and damping.

use std::fmt;

use spidar_rt::Rig;
use spidar_sim::boxer::{parse_boxer, BOXER_RON};
use spidar_world::walls::WallsScene;
use spidar_world::Scene;

use crate::zwidth::{run_bout, Bout, BoutResult, HandModel, Place, AXES};

/// The sweep's set-up.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepOptions {
    /// Stiffnesses: `k_steps` log-spaced from `k_min` to `k_max` (N/m).
    pub k_min: f64,
    pub k_max: f64,
    pub k_steps: usize,
    /// Dampings: `b_steps` evenly from `b_min` to `b_max` (N s/m).
    pub b_min: f64,
    pub b_max: f64,
    pub b_steps: usize,
    /// Loop rates (Hz).
    pub rates_hz: Vec<f64>,
    pub hand: HandModel,
    /// Seconds of each bout after the press.
    pub seconds: f64,
    pub motor_time_constant_s: f64,
}

impl Default for SweepOptions {
    fn default() -> Self {
        SweepOptions {
            k_min: 100.0,
            k_max: 20_000.0,
            k_steps: 12,
            b_min: -5.0,
            b_max: 20.0,
            b_steps: 6,
            rates_hz: vec![1000.0, 500.0],
            hand: HandModel::default(),
            seconds: 3.0,
            motor_time_constant_s: 0.0,
        }
    }
}

impl SweepOptions {
    pub fn ks(&self) -> Vec<f64> {
        let n = self.k_steps.max(2);
        let r = (self.k_max / self.k_min).ln();
        (0..n).map(|i| self.k_min * (r * i as f64 / (n - 1) as f64).exp()).collect()
    }
    pub fn bs(&self) -> Vec<f64> {
        let n = self.b_steps.max(2);
        (0..n).map(|i| self.b_min + (self.b_max - self.b_min) * i as f64 / (n - 1) as f64).collect()
    }
}

/// The (axis, place) cases of every grid point: each axis at each place.
pub fn cases() -> Vec<(usize, Place)> {
    Place::ALL.iter().flat_map(|p| (0..AXES.len()).map(move |a| (a, *p))).collect()
}

/// One rate's grid: `passive[bi][ki][case]`.
#[derive(Clone, Debug)]
pub struct RateGrid {
    pub rate_hz: f64,
    pub passive: Vec<Vec<Vec<bool>>>,
}

impl RateGrid {
    /// Per B: the largest K of the grid below which every K was passive in every case (None:
    /// not even the smallest).
    pub fn boundary(&self, ks: &[f64]) -> Vec<Option<f64>> {
        self.passive
            .iter()
            .map(|row| {
                let n = row.iter().take_while(|cs| cs.iter().all(|p| *p)).count();
                n.checked_sub(1).map(|i| ks[i])
            })
            .collect()
    }
}

/// Colgate and Schenkel's sampled-wall bound: passive while `b > K T / 2 + |B|`.
pub fn colgate_k_max(b: f64, d: f64, period_s: f64) -> f64 {
    (2.0 * (b - d.abs()) / period_s).max(0.0)
}

/// The loop's own stability bound (rt-loop `bounds.rs`, docs/safety.md section 6): a spring
/// rendered one tick late and held acts 1.5 T late, `K < 2 (b + B) / (3 T)`.
pub fn delayed_k_max(b: f64, d: f64, period_s: f64) -> f64 {
    (2.0 * (b + d) / (3.0 * period_s)).max(0.0)
}

/// A shipped scene's contact: its stiffness as the rig renders it (softened to the rig's limit)
/// and its damping, and the bouts run at them at the rig's rate.
#[derive(Clone, Debug)]
pub struct SceneCheck {
    pub what: String,
    pub k_n_per_m: f64,
    pub d_n_s_per_m: f64,
    pub results: Vec<BoutResult>,
}

impl SceneCheck {
    pub fn passive(&self) -> bool {
        self.results.iter().all(|r| r.passive())
    }
}

/// The shipped scenes' contacts: the walls scene's proxies (from the model it sends), the crowd's
/// proxies (its constants) and the boxing scene's avatar-hand contact (no damping; its stiffness
/// at most the coupling spring, configs/boxer.ron), each with K softened to the rig's limit.
pub fn shipped_contacts(rig: &Rig) -> anyhow::Result<Vec<(String, f64, f64)>> {
    let limit = rig.hands[crate::zwidth::HAND].stiffness_limit_n_per_m;
    let mut out: Vec<(String, f64, f64)> = Vec::new();
    let model = WallsScene::builtin().step(0.0, &[]);
    for p in model.proxies() {
        out.push(("walls scene proxy".into(), p.k_n_per_m, p.d_n_s_per_m));
    }
    use spidar_world::crowd::{PROXY_D_N_S_PER_M, PROXY_K_N_PER_M};
    out.push(("crowd scene proxy".into(), PROXY_K_N_PER_M, PROXY_D_N_S_PER_M));
    let boxer = parse_boxer(BOXER_RON, "configs/boxer.ron")?;
    out.push(("boxing avatar-hand contact (at most)".into(), boxer.coupling_k_n_per_m, 0.0));
    let mut seen: Vec<(String, f64, f64)> = Vec::new();
    for (what, k, d) in out {
        let k = k.min(limit);
        if !seen.iter().any(|s| s.1 == k && s.2 == d && s.0 == what) {
            seen.push((what, k, d));
        }
    }
    Ok(seen)
}

fn bout(o: &SweepOptions, k: f64, d: f64, (axis, place): (usize, Place), period_s: f64) -> Bout {
    Bout {
        axis,
        place,
        period_s,
        hand: o.hand,
        seconds: o.seconds,
        motor_time_constant_s: o.motor_time_constant_s,
        ..Bout::new(k, d)
    }
}

/// Runs each shipped contact at the rig's own rate in every case.
pub fn check_scenes(rig: &Rig, o: &SweepOptions) -> anyhow::Result<Vec<SceneCheck>> {
    let mut out = Vec::new();
    for (what, k, d) in shipped_contacts(rig)? {
        let results = cases()
            .into_iter()
            .map(|c| run_bout(rig, &bout(o, k, d, c, rig.period_s)))
            .collect::<Result<_, _>>()?;
        out.push(SceneCheck { what, k_n_per_m: k, d_n_s_per_m: d, results });
    }
    Ok(out)
}

/// The whole sweep's result.
#[derive(Clone, Debug)]
pub struct ZwidthReport {
    pub options: SweepOptions,
    pub rig_rate_hz: f64,
    pub grids: Vec<RateGrid>,
    pub scenes: Vec<SceneCheck>,
    pub bouts: usize,
}

/// Runs the grid at every rate, then the shipped scenes' contacts.
pub fn sweep(rig: &Rig, o: &SweepOptions) -> anyhow::Result<ZwidthReport> {
    let (ks, bs) = (o.ks(), o.bs());
    let mut grids = Vec::new();
    let mut bouts = 0;
    anyhow::ensure!(
        !o.rates_hz.is_empty(),
        "no loop rate to sweep: give at least one (e.g. --rates 1000,500)"
    );
    for &rate in &o.rates_hz {
        anyhow::ensure!(
            rate.is_finite() && (100.0..=20_000.0).contains(&rate),
            "a loop rate of {rate} Hz: give rates from 100 to 20000 Hz (e.g. --rates 1000,500)"
        );
    }
    for &rate in &o.rates_hz {
        let mut passive = Vec::new();
        for &d in &bs {
            let mut row = Vec::new();
            for &k in &ks {
                let mut cs = Vec::new();
                for c in cases() {
                    cs.push(run_bout(rig, &bout(o, k, d, c, 1.0 / rate))?.passive());
                    bouts += 1;
                }
                row.push(cs);
            }
            passive.push(row);
        }
        grids.push(RateGrid { rate_hz: rate, passive });
    }
    let scenes = check_scenes(rig, o)?;
    bouts += scenes.iter().map(|s| s.results.len()).sum::<usize>();
    Ok(ZwidthReport { options: o.clone(), rig_rate_hz: 1.0 / rig.period_s, grids, scenes, bouts })
}

impl fmt::Display for ZwidthReport {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let o = &self.options;
        let (ks, bs) = (o.ks(), o.bs());
        let h = &o.hand;
        let n = cases().len();
        writeln!(
            f,
            "spidar bench zwidth: walls on the simulated rig through the rt-loop (virtual clock), {} bouts",
            self.bouts
        )?;
        writeln!(
            f,
            "hand {} kg, {} N/m, {} N s/m pressing {} N; {} s bouts, judged on the last 1 s; motors' lag {} ms",
            h.mass_kg,
            h.k_n_per_m,
            h.d_n_s_per_m,
            h.press_n,
            o.seconds,
            o.motor_time_constant_s * 1e3
        )?;
        writeln!(
            f,
            "cases per cell: x, y, z at home and off-centre ({n}); cell = cases passive ('+' all, '.' none)"
        )?;
        for g in &self.grids {
            let t = 1.0 / g.rate_hz;
            writeln!(f, "\n{} Hz   K (N/m) ->", g.rate_hz)?;
            write!(f, "{:>8}", "B")?;
            for k in &ks {
                write!(f, "{:>7.0}", k)?;
            }
            writeln!(f, "   boundary  Colgate  1.5T-delay")?;
            let bound = g.boundary(&ks);
            for (bi, d) in bs.iter().enumerate() {
                write!(f, "{:>8.1}", d)?;
                for cs in &g.passive[bi] {
                    let p = cs.iter().filter(|p| **p).count();
                    let c = if p == n {
                        "+".into()
                    } else if p == 0 {
                        ".".into()
                    } else {
                        p.to_string()
                    };
                    write!(f, "{:>7}", c)?;
                }
                let b = h.d_n_s_per_m;
                let bnd = bound[bi].map_or("none".into(), |k| format!("{k:.0}"));
                writeln!(
                    f,
                    "   {:>8}  {:>7.0}  {:>10.0}",
                    bnd,
                    colgate_k_max(b, *d, t),
                    delayed_k_max(b, *d, t)
                )?;
            }
        }
        writeln!(
            f,
            "\nboundary: largest K of the grid passive in every case with every smaller K; Colgate: b > K T/2 + |B|; \
             1.5T-delay: K < 2 (b + B) / (3 T); b = the hand's {} N s/m (the simulated rig has no friction)",
            h.d_n_s_per_m
        )?;
        writeln!(
            f,
            "\nshipped scenes' contacts at the rig's rate ({} Hz), K softened to the rig's limit:",
            self.rig_rate_hz
        )?;
        for s in &self.scenes {
            let worst = s.results.iter().map(|r| r.pp_last_m).fold(0.0, f64::max);
            let energy = s.results.iter().map(|r| r.energy_j).fold(f64::NEG_INFINITY, f64::max);
            writeln!(
                f,
                "  {:<38} K {:>6.0} N/m  B {:>5.1} N s/m: {} ({} of {n} cases passive; largest p-p {:.3} mm, energy {:.2} mJ)",
                s.what,
                s.k_n_per_m,
                s.d_n_s_per_m,
                if s.passive() { "passive" } else { "NOT PASSIVE" },
                s.results.iter().filter(|r| r.passive()).count(),
                worst * 1e3,
                energy * 1e3
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_boundary_is_the_last_k_passive_in_every_case_with_every_smaller_one() {
        let ks = [100.0, 1000.0, 10_000.0];
        let (t, f) = (true, false);
        let g = RateGrid {
            rate_hz: 1000.0,
            passive: vec![
                vec![vec![t, t], vec![t, f], vec![t, t]], // a case fails at 1000: 100, not 10,000
                vec![vec![t, t], vec![t, t], vec![t, t]],
                vec![vec![f, t], vec![t, t], vec![t, t]],
            ],
        };
        assert_eq!(g.boundary(&ks), [Some(100.0), Some(10_000.0), None]);
        assert_eq!(colgate_k_max(8.0, -3.0, 0.001), 10_000.0);
        assert_eq!(delayed_k_max(8.0, -3.0, 0.001), 10_000.0 / 3.0);
    }

    #[test]
    fn a_small_sweep_reports_its_boundary_and_draws_every_grid_point() {
        let rig = Rig::default_rig();
        let o = SweepOptions {
            k_min: 1000.0,
            k_max: 15_000.0,
            k_steps: 2,
            b_steps: 2,
            rates_hz: vec![1000.0],
            ..SweepOptions::default()
        };
        let r = sweep(&rig, &o).unwrap();
        assert_eq!(r.bouts, 2 * 2 * cases().len() + r.scenes.len() * cases().len());
        // 1,000 N/m is passive at B = -5 and 20; 15,000 N/m at neither.
        assert_eq!(r.grids[0].boundary(&o.ks()), [Some(1000.0), Some(1000.0)]);
        let text = r.to_string();
        assert!(
            text.contains("1000 Hz") && text.contains("NOT PASSIVE") != r.scenes.iter().all(|s| s.passive()),
            "{text}"
        );
        let path = std::env::temp_dir().join(format!("spidar-zwidth-test-{}.svg", std::process::id()));
        crate::zwidth_plot::zwidth_svg(&r, &path).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_file(&path).ok();
        assert_eq!(svg.matches("<circle").count(), 4, "one mark per grid point");
        assert!(svg.contains("1000 Hz loop"));
    }

    /// Item 4 of issue 27: every contact the shipped scenes send, at the stiffness the shipped
    /// rig renders it with, is passive at the rig's 1 kHz along x, y, z at home and off-centre.
    #[test]
    fn the_shipped_scenes_contacts_are_passive_at_the_shipped_rigs_rate() {
        let rig = Rig::default_rig();
        let contacts = shipped_contacts(&rig).unwrap();
        let kd: Vec<(f64, f64)> = contacts.iter().map(|c| (c.1, c.2)).collect();
        for expected in [(2000.0, 5.0), (1000.0, 5.0), (5000.0, 100.0), (3000.0, 0.0)] {
            assert!(kd.contains(&expected), "{expected:?} not among {contacts:?}");
        }
        let checks = check_scenes(&rig, &SweepOptions::default()).unwrap();
        for c in &checks {
            assert_eq!(c.results.len(), cases().len());
            assert!(c.passive(), "{} K {} B {}: {:?}", c.what, c.k_n_per_m, c.d_n_s_per_m, c.results);
        }
    }
}

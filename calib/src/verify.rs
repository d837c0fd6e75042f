//! Verification: with a geometry (fitted or configured), the grip is put on check points that the
//! fit never saw, and the position the rig computes there is compared with the known point.
//!
//! It must never use fitted data to judge the fit: check points come from the jig file's
//! `check_points`, recorded afresh.

use glam::DVec3;
use spidar_rt::Rig;

use crate::jig::JigFile;
use crate::model::HandGeometry;
use crate::record::{Operator, Recorder, Request};
use crate::ticks::TickSource;
use crate::CalibError;

#[derive(Clone, Debug)]
pub struct CheckResult {
    pub hand: usize,
    pub label: String,
    pub known_m: DVec3,
    pub measured_m: DVec3,
    /// RMS string residual of the position solve there.
    pub residual_m: f64,
}

impl CheckResult {
    pub fn error_m(&self) -> f64 {
        self.known_m.distance(self.measured_m)
    }
}

#[derive(Clone, Debug, Default)]
pub struct VerifyReport {
    pub checks: Vec<CheckResult>,
}

impl VerifyReport {
    pub fn max_error_m(&self) -> f64 {
        self.checks.iter().map(CheckResult::error_m).fold(0.0, f64::max)
    }
    pub fn rms_error_m(&self) -> f64 {
        let n = self.checks.len().max(1) as f64;
        (self.checks.iter().map(|c| c.error_m().powi(2)).sum::<f64>() / n).sqrt()
    }
}

impl std::fmt::Display for VerifyReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "  {:<4} {:<24} {:>28} {:>10} {:>12}",
            "hand", "check point", "error (x, y, z) mm", "|error|", "residual"
        )?;
        for c in &self.checks {
            let e = (c.measured_m - c.known_m) * 1e3;
            writeln!(
                f,
                "  {:<4} {:<24} {:>28} {:>7.3} mm {:>9.3} mm",
                c.hand,
                c.label,
                format!("({:+.3}, {:+.3}, {:+.3})", e.x, e.y, e.z),
                c.error_m() * 1e3,
                c.residual_m * 1e3
            )?;
        }
        write!(
            f,
            "  {} check points: position error RMS {:.3} mm, max {:.3} mm",
            self.checks.len(),
            self.rms_error_m() * 1e3,
            self.max_error_m() * 1e3
        )
    }
}

/// Records every check point of `hands` with `geometry` and reports the position error.
pub fn verify<S: TickSource, O: Operator<S> + ?Sized>(
    rec: &mut Recorder<'_, S>,
    op: &mut O,
    rig: &Rig,
    geometry: &[HandGeometry; 2],
    jig: &JigFile,
    hands: &[usize],
) -> Result<VerifyReport, CalibError> {
    let points: Vec<_> = jig.check_points.iter().filter(|p| hands.contains(&p.hand)).collect();
    if points.is_empty() {
        return Err(CalibError::Recording(
            "the jig file has no check points for these hands: add check_points".into(),
        ));
    }
    let mut report = VerifyReport::default();
    for (n, p) in points.iter().enumerate() {
        let req = Request::Jig { label: p.label.clone(), at_m: p.at() };
        op.tell(&format!("[check {}/{}] hand {}: {req}", n + 1, points.len(), p.hand));
        let (counts, _) = rec.record_at(op, p.hand, &req)?;
        let (pos, residual) = geometry[p.hand].position(&counts).ok_or_else(|| {
            CalibError::Recording(format!("check point {}: the lengths give no valid position", p.label))
        })?;
        report.checks.push(CheckResult {
            hand: p.hand,
            label: p.label.clone(),
            known_m: p.at(),
            measured_m: pos,
            residual_m: residual,
        });
    }
    for &h in hands {
        op.request(rec.ticks(), h, &Request::Home { at_m: rig.hands[h].home_m })?;
    }
    Ok(report)
}

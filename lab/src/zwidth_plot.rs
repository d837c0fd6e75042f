//! The Z-width plot (`spidar bench zwidth --svg FILE`): one panel per loop rate, wall stiffness K
//! on a log axis, damping B up; each grid point marked passive in every case, in none, or in
//! some; the Colgate-Schenkel bound and the loop's 1.5-tick-delay bound drawn beside them.
//!
//! SVG through `plotters` without its font features (text is left to the viewer's fonts). Must
//! never draw a mark the report's grid does not hold.

use std::path::Path;

use plotters::prelude::*;

use crate::zwidth_sweep::{cases, colgate_k_max, delayed_k_max, ZwidthReport};

const PASSIVE: RGBColor = RGBColor(27, 120, 55);
const MIXED: RGBColor = RGBColor(230, 140, 30);
const ACTIVE: RGBColor = RGBColor(200, 30, 30);
const COLGATE: RGBColor = RGBColor(40, 70, 200);
const DELAYED: RGBColor = RGBColor(120, 120, 120);

/// Writes the plot of `report` to `path`.
pub fn zwidth_svg(report: &ZwidthReport, path: &Path) -> anyhow::Result<()> {
    let err = |e: String| anyhow::anyhow!("writing the Z-width plot {}: {e}", path.display());
    let o = &report.options;
    let (ks, bs) = (o.ks(), o.bs());
    let n = cases().len();
    let width = 520 * report.grids.len().max(1) as u32;
    let root = SVGBackend::new(path, (width, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let title = format!(
        "Z-width, simulated rig through the loop: hand {} kg, {} N s/m; green passive in all {n} cases, orange in some, red in none",
        o.hand.mass_kg, o.hand.d_n_s_per_m
    );
    let (top, body) = root.split_vertically(36);
    top.titled(&title, ("sans-serif", 14)).map_err(|e| err(e.to_string()))?;
    let panels = body.split_evenly((1, report.grids.len().max(1)));
    let (k_lo, k_hi) = (o.k_min * 0.8, o.k_max * 1.25);
    let pad = (o.b_max - o.b_min) * 0.06;
    let b = o.hand.d_n_s_per_m;
    for (g, area) in report.grids.iter().zip(panels.iter()) {
        let t = 1.0 / g.rate_hz;
        let mut chart = ChartBuilder::on(area)
            .caption(format!("{} Hz loop", g.rate_hz), ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(44)
            .build_cartesian_2d((k_lo..k_hi).log_scale(), (o.b_min - pad)..(o.b_max + pad))
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_mesh()
            .x_desc("wall stiffness K (N/m)")
            .y_desc("wall damping B (N s/m)")
            .draw()
            .map_err(|e| err(e.to_string()))?;
        let bline = |f: &dyn Fn(f64) -> f64| -> Vec<(f64, f64)> {
            let steps = 200;
            (0..=steps)
                .map(|i| o.b_min + (o.b_max - o.b_min) * i as f64 / steps as f64)
                .map(|d| (f(d), d))
                .filter(|(k, _)| *k >= k_lo && *k <= k_hi)
                .collect()
        };
        let colgate = bline(&|d| colgate_k_max(b, d, t));
        chart
            .draw_series(LineSeries::new(colgate, COLGATE.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?
            .label(format!("Colgate b > KT/2 + |B|, b = {b} N s/m"))
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], COLGATE.stroke_width(2)));
        let delayed = bline(&|d| delayed_k_max(b, d, t));
        chart
            .draw_series(LineSeries::new(delayed, DELAYED.stroke_width(2)))
            .map_err(|e| err(e.to_string()))?
            .label("1.5-tick delay K < 2 (b + B) / (3T)")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], DELAYED.stroke_width(2)));
        let mut points = Vec::new();
        for (bi, d) in bs.iter().enumerate() {
            for (ki, k) in ks.iter().enumerate() {
                let p = g.passive[bi][ki].iter().filter(|p| **p).count();
                points.push(((*k, *d), p));
            }
        }
        chart
            .draw_series(points.iter().map(|&(at, p)| {
                let colour = if p == n {
                    PASSIVE
                } else if p == 0 {
                    ACTIVE
                } else {
                    MIXED
                };
                Circle::new(at, 5, colour.filled())
            }))
            .map_err(|e| err(e.to_string()))?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .border_style(BLACK)
            .background_style(WHITE.mix(0.85))
            .draw()
            .map_err(|e| err(e.to_string()))?;
    }
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

//! SVG plots of a fit: residuals per pose and string, and how far the fit moved each anchor from
//! its configured position.
//!
//! SVG through `plotters` without its font features, so nothing needs fontconfig or freetype; the
//! text is left to the SVG viewer's fonts. Plotting must never change or hide a number the text
//! report gives: it draws the same `HandFit`.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use crate::fit::HandFit;
use crate::CalibError;

const STRING_COLOURS: [RGBColor; 4] =
    [RGBColor(31, 119, 180), RGBColor(255, 127, 14), RGBColor(44, 160, 44), RGBColor(214, 39, 40)];

fn plot_err(file: &Path) -> impl Fn(String) -> CalibError + '_ {
    move |message| CalibError::Plot { file: file.display().to_string(), message }
}

/// Residual (mm) of every string at every pose; outliers (down-weighted) drawn hollow.
pub fn residuals_svg(fit: &HandFit, path: &Path) -> Result<(), CalibError> {
    let err = plot_err(path);
    let n = fit.residuals_m.len();
    let max = fit.residuals_m.iter().flatten().map(|r| r.abs() * 1e3).fold(0.01, f64::max) * 1.15;
    let root = SVGBackend::new(path, (900, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("hand {}: residual per pose and string (RMS {:.4} mm)", fit.hand, fit.rms_m * 1e3),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.5..(n as f64 - 0.5), -max..max)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("pose (recording order)")
        .y_desc("measured - model (mm)")
        .draw()
        .map_err(|e| err(e.to_string()))?;
    for (i, colour) in STRING_COLOURS.iter().enumerate() {
        let pts: Vec<(f64, f64, bool)> = fit
            .residuals_m
            .iter()
            .zip(&fit.weights)
            .enumerate()
            .map(|(k, (r, w))| (k as f64 + (i as f64 - 1.5) * 0.12, r[i] * 1e3, w[i] > 0.99))
            .collect();
        chart
            .draw_series(pts.iter().map(|&(x, y, full)| {
                let style = if full { colour.filled() } else { colour.stroke_width(1) };
                Circle::new((x, y), 3, style)
            }))
            .map_err(|e| err(e.to_string()))?
            .label(format!("string {i}"))
            .legend(move |(x, y)| Circle::new((x, y), 3, colour.filled()));
    }
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

/// Fitted minus configured anchor position (mm), per anchor and axis, with the fit's 3-sigma bars.
pub fn anchors_svg(fit: &HandFit, path: &Path) -> Result<(), CalibError> {
    let err = plot_err(path);
    let d: Vec<[f64; 3]> = (0..4)
        .map(|i| ((fit.geometry.anchors_m[i] - fit.configured.anchors_m[i]) * 1e3).to_array())
        .collect();
    let max = d.iter().flatten().map(|v| v.abs()).fold(1.0, f64::max) * 1.2;
    let root = SVGBackend::new(path, (900, 420)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!("hand {}: fitted minus configured anchors (x, y, z per anchor)", fit.hand),
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(36)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.5..3.5, -max..max)
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("anchor (bars: x, y, z)")
        .y_desc("change (mm)")
        .x_labels(4)
        .x_label_formatter(&|v: &f64| format!("anchor {}", v.round()))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    const AXIS_COLOURS: [RGBColor; 3] =
        [RGBColor(214, 39, 40), RGBColor(44, 160, 44), RGBColor(31, 119, 180)];
    for (c, colour) in AXIS_COLOURS.iter().enumerate() {
        chart
            .draw_series((0..4).map(|i| {
                let x0 = i as f64 - 0.3 + c as f64 * 0.2;
                Rectangle::new([(x0, 0.0), (x0 + 0.18, d[i][c])], colour.filled())
            }))
            .map_err(|e| err(e.to_string()))?
            .label(["x", "y", "z"][c])
            .legend(move |(x, y)| Rectangle::new([(x, y - 4), (x + 8, y + 4)], colour.filled()));
        chart
            .draw_series((0..4).map(|i| {
                let x = i as f64 - 0.21 + c as f64 * 0.2;
                let s = fit.anchor_std_m[i][c] * 3e3;
                PathElement::new(vec![(x, d[i][c] - s), (x, d[i][c] + s)], BLACK.stroke_width(2))
            }))
            .map_err(|e| err(e.to_string()))?;
    }
    chart
        .configure_series_labels()
        .border_style(BLACK)
        .background_style(WHITE.mix(0.8))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))?;
    Ok(())
}

/// Both plots for a hand into `dir`; returns the files written.
pub fn write_plots(fit: &HandFit, dir: &Path) -> Result<Vec<PathBuf>, CalibError> {
    std::fs::create_dir_all(dir).map_err(|source| CalibError::Io {
        file: dir.display().to_string(),
        what: "cannot create the plot folder",
        source,
    })?;
    let r = dir.join(format!("hand{}-residuals.svg", fit.hand));
    let a = dir.join(format!("hand{}-anchors.svg", fit.hand));
    residuals_svg(fit, &r)?;
    anchors_svg(fit, &a)?;
    Ok(vec![r, a])
}

//! The training-curve figure: imitation loss per epoch, TD loss per logging block, and the
//! training and validation success rates against RL episodes.

use crate::error::SarlError;
use crate::train::Progress;
use plotters::prelude::*;
use std::path::Path;

const BLUE: RGBColor = RGBColor(31, 119, 180);
const ORANGE: RGBColor = RGBColor(255, 127, 14);
const RED: RGBColor = RGBColor(214, 39, 40);

/// Draws the three panels as a PNG at `path`.
pub fn training_curve(p: &Progress, path: &Path) -> Result<(), SarlError> {
    let err = |e: String| SarlError::Plot {
        path: path.to_path_buf(),
        message: e,
    };
    let root = BitMapBackend::new(path, (1500, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let panels = root.split_evenly((1, 3));

    let log_range = |v: &[f64]| {
        let pos: Vec<f64> = v
            .iter()
            .copied()
            .filter(|x| x.is_finite() && *x > 0.0)
            .collect();
        let lo = pos.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = pos.iter().copied().fold(0.0, f64::max);
        if pos.is_empty() {
            (1e-4, 1.0)
        } else {
            (lo * 0.8, hi * 1.25)
        }
    };

    // Imitation loss.
    let il: Vec<(f64, f64)> = p
        .il_log
        .iter()
        .filter(|l| l.loss.is_finite() && l.loss > 0.0)
        .map(|l| (l.step as f64, l.loss))
        .collect();
    let (lo, hi) = log_range(&il.iter().map(|x| x.1).collect::<Vec<_>>());
    let max_epoch = il.iter().map(|x| x.0).fold(1.0, f64::max);
    let mut c = ChartBuilder::on(&panels[0])
        .caption("imitation (ORCA demonstrations)", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(0.0..max_epoch, (lo..hi).log_scale())
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("epoch")
        .y_desc("value MSE")
        .y_label_formatter(&|v| format!("{v:.1e}"))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    c.draw_series(LineSeries::new(il, BLUE.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?;

    // TD loss.
    let rl: Vec<(f64, f64)> = p
        .rl_log
        .iter()
        .filter(|l| l.loss.is_finite() && l.loss > 0.0)
        .map(|l| (l.step as f64, l.loss))
        .collect();
    let (lo, hi) = log_range(&rl.iter().map(|x| x.1).collect::<Vec<_>>());
    let max_ep = p
        .rl_log
        .iter()
        .map(|l| l.step as f64)
        .chain(p.validation.iter().map(|v| v.episode as f64))
        .fold(1.0, f64::max);
    let mut c = ChartBuilder::on(&panels[1])
        .caption("TD learning: loss", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(0.0..max_ep, (lo..hi).log_scale())
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("RL episode")
        .y_desc("TD MSE (block mean)")
        .y_label_formatter(&|v| format!("{v:.1e}"))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    c.draw_series(LineSeries::new(rl, BLUE.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?;

    // Success rates.
    let mut c = ChartBuilder::on(&panels[2])
        .caption("circle crossing: outcome rates", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..max_ep, 0.0..1.0)
        .map_err(|e| err(e.to_string()))?;
    c.configure_mesh()
        .x_desc("RL episode")
        .y_desc("rate")
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let train_sr: Vec<(f64, f64)> = p
        .rl_log
        .iter()
        .map(|l| (l.step as f64, l.success_rate))
        .collect();
    c.draw_series(LineSeries::new(train_sr, BLUE.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?
        .label("training success (ε-greedy)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLUE.stroke_width(2)));
    let val_sr: Vec<(f64, f64)> = p
        .validation
        .iter()
        .map(|v| (v.episode as f64, v.success_rate))
        .collect();
    c.draw_series(LineSeries::new(val_sr.clone(), ORANGE.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?
        .label("validation success (greedy)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], ORANGE.stroke_width(2)));
    c.draw_series(
        val_sr
            .iter()
            .map(|&(x, y)| Circle::new((x, y), 3, ORANGE.filled())),
    )
    .map_err(|e| err(e.to_string()))?;
    let val_col: Vec<(f64, f64)> = p
        .validation
        .iter()
        .map(|v| (v.episode as f64, v.collision_rate))
        .collect();
    c.draw_series(LineSeries::new(val_col, RED.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?
        .label("validation collision")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED.stroke_width(2)));
    c.configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

//! The training-curve figure: imitation loss per epoch, TD loss per logging block, and the
//! training and validation success rates against RL episodes.

use crate::error::SarlError;
use crate::train::Progress;
use plotters::prelude::*;
use std::path::Path;

const BLUE: RGBColor = RGBColor(31, 119, 180);
const ORANGE: RGBColor = RGBColor(255, 127, 14);
const RED: RGBColor = RGBColor(214, 39, 40);

/// Draws the three panels as a PNG at `path`: the imitation loss, the TD loss and the outcome
/// rates.
pub fn training_curve(p: &Progress, path: &Path) -> Result<(), SarlError> {
    let err = |e: String| SarlError::Plot {
        path: path.to_path_buf(),
        message: e,
    };
    let root = BitMapBackend::new(path, (1500, 480)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let panels = root.split_evenly((1, 3));
    imitation_panel(&panels[0], p).map_err(err)?;
    let max_ep = p
        .rl_log
        .iter()
        .map(|l| l.step as f64)
        .chain(p.validation.iter().map(|v| v.episode as f64))
        .fold(1.0, f64::max);
    td_panel(&panels[1], p, max_ep).map_err(err)?;
    outcome_panel(&panels[2], p, max_ep).map_err(err)?;
    root.present().map_err(|e| err(e.to_string()))
}

/// A linear loss axis's top: a little above the largest finite value (1 when there is none).
fn loss_top(v: &[f64]) -> f64 {
    let hi = v
        .iter()
        .copied()
        .filter(|x| x.is_finite())
        .fold(0.0, f64::max);
    if hi > 0.0 { hi * 1.1 } else { 1.0 }
}

/// The panel type: a third of the figure.
type Panel<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// The imitation loss per epoch.
fn imitation_panel(panel: &Panel<'_>, p: &Progress) -> Result<(), String> {
    let il: Vec<(f64, f64)> = p
        .il_log
        .iter()
        .filter(|l| l.loss.is_finite() && l.loss > 0.0)
        .map(|l| (l.step as f64, l.loss))
        .collect();
    let hi = loss_top(&il.iter().map(|x| x.1).collect::<Vec<_>>());
    let max_epoch = il.iter().map(|x| x.0).fold(1.0, f64::max);
    let mut c = ChartBuilder::on(panel)
        .caption("imitation (ORCA demonstrations)", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(0.0..max_epoch, 0.0..hi)
        .map_err(|e| e.to_string())?;
    c.configure_mesh()
        .x_desc("epoch")
        .y_desc("value MSE (epoch mean)")
        .y_label_formatter(&|v| format!("{v:.3}"))
        .draw()
        .map_err(|e| e.to_string())?;
    c.draw_series(LineSeries::new(il, BLUE.stroke_width(2)))
        .map_err(|e| e.to_string())?;

    Ok(())
}

/// The TD loss per RL episode (x axis up to `max_ep`).
fn td_panel(panel: &Panel<'_>, p: &Progress, max_ep: f64) -> Result<(), String> {
    let rl: Vec<(f64, f64)> = p
        .rl_log
        .iter()
        .filter(|l| l.loss.is_finite() && l.loss > 0.0)
        .map(|l| (l.step as f64, l.loss))
        .collect();
    let hi = loss_top(&rl.iter().map(|x| x.1).collect::<Vec<_>>());
    let mut c = ChartBuilder::on(panel)
        .caption("TD learning: loss", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(64)
        .build_cartesian_2d(0.0..max_ep, 0.0..hi)
        .map_err(|e| e.to_string())?;
    c.configure_mesh()
        .x_desc("RL episode")
        .y_desc("TD MSE (mean per checkpoint block)")
        .y_label_formatter(&|v| format!("{v:.4}"))
        .draw()
        .map_err(|e| e.to_string())?;
    c.draw_series(LineSeries::new(rl, BLUE.stroke_width(2)))
        .map_err(|e| e.to_string())?;

    Ok(())
}

/// Training success, validation success and validation collisions per RL episode.
fn outcome_panel(panel: &Panel<'_>, p: &Progress, max_ep: f64) -> Result<(), String> {
    let mut c = ChartBuilder::on(panel)
        .caption("circle crossing: outcome rates", ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0.0..max_ep, 0.0..1.0)
        .map_err(|e| e.to_string())?;
    c.configure_mesh()
        .x_desc("RL episode")
        .y_desc("rate")
        .draw()
        .map_err(|e| e.to_string())?;
    let train_sr: Vec<(f64, f64)> = p
        .rl_log
        .iter()
        .map(|l| (l.step as f64, l.success_rate))
        .collect();
    c.draw_series(LineSeries::new(train_sr, BLUE.stroke_width(2)))
        .map_err(|e| e.to_string())?
        .label("training success (ε-greedy)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], BLUE.stroke_width(2)));
    let val_sr: Vec<(f64, f64)> = p
        .validation
        .iter()
        .map(|v| (v.episode as f64, v.success_rate))
        .collect();
    c.draw_series(LineSeries::new(val_sr.clone(), ORANGE.stroke_width(2)))
        .map_err(|e| e.to_string())?
        .label("validation success (greedy)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], ORANGE.stroke_width(2)));
    c.draw_series(
        val_sr
            .iter()
            .map(|&(x, y)| Circle::new((x, y), 3, ORANGE.filled())),
    )
    .map_err(|e| e.to_string())?;
    let val_col: Vec<(f64, f64)> = p
        .validation
        .iter()
        .map(|v| (v.episode as f64, v.collision_rate))
        .collect();
    c.draw_series(LineSeries::new(val_col, RED.stroke_width(2)))
        .map_err(|e| e.to_string())?
        .label("validation collision")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED.stroke_width(2)));
    c.configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::train::{LogPoint, ValPoint};

    #[test]
    fn draws_a_png() {
        let p = Progress {
            il_log: (1..=5)
                .map(|e| LogPoint {
                    step: e,
                    loss: 0.05 / e as f64,
                    success_rate: 0.0,
                })
                .collect(),
            rl_log: (1..=4)
                .map(|k| LogPoint {
                    step: 100 * k,
                    loss: 0.01 / k as f64,
                    success_rate: 0.2 * k as f64,
                })
                .collect(),
            validation: (0..=4)
                .map(|k| ValPoint {
                    episode: 100 * k,
                    success_rate: 0.2 * k as f64,
                    collision_rate: 0.1,
                    timeout_rate: 0.0,
                })
                .collect(),
            ..Progress::default()
        };
        let path = std::env::temp_dir().join(format!("sarl-curve-{}.png", std::process::id()));
        training_curve(&p, &path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"));
        let _ = std::fs::remove_file(&path);
    }
}

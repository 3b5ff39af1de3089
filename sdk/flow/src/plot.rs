//! The loss-curve figure of a training run.

use crate::error::CfmError;
use crate::train::LossRecord;
use plotters::prelude::*;
use std::path::Path;

/// Draws training and validation loss against optimiser step (log-scaled loss) as a PNG.
pub fn loss_curve(path: &Path, history: &[LossRecord], title: &str) -> Result<(), CfmError> {
    let err = |e: String| CfmError::Plot {
        path: path.to_path_buf(),
        message: e,
    };
    let finite = |v: f64| v.is_finite() && v > 0.0;
    let values: Vec<f64> = history
        .iter()
        .flat_map(|r| [r.train_loss, r.val_loss])
        .filter(|&v| finite(v))
        .collect();
    if values.is_empty() {
        return Err(err("no finite loss values to draw".into()));
    }
    let lo = values.iter().copied().fold(f64::INFINITY, f64::min) * 0.9;
    let hi = values.iter().copied().fold(0.0, f64::max) * 1.1;
    let max_step = history.iter().map(|r| r.step).max().unwrap_or(1).max(1);

    let root = BitMapBackend::new(path, (900, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(e.to_string()))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(42)
        .y_label_area_size(64)
        .build_cartesian_2d(0u64..max_step, (lo..hi).log_scale())
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_mesh()
        .x_desc("optimiser step")
        .y_desc("CFM loss (standardised, Eq. 3)")
        .y_label_formatter(&|v| format!("{v:.3}"))
        .draw()
        .map_err(|e| err(e.to_string()))?;
    let train: Vec<(u64, f64)> = history
        .iter()
        .filter(|r| finite(r.train_loss))
        .map(|r| (r.step, r.train_loss))
        .collect();
    let val: Vec<(u64, f64)> = history
        .iter()
        .filter(|r| finite(r.val_loss))
        .map(|r| (r.step, r.val_loss))
        .collect();
    let blue = RGBColor(31, 119, 180);
    let orange = RGBColor(255, 127, 14);
    chart
        .draw_series(LineSeries::new(train, blue.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?
        .label("train (mean over interval)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], blue.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(val.clone(), orange.stroke_width(2)))
        .map_err(|e| err(e.to_string()))?
        .label("validation (EMA weights)")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], orange.stroke_width(2)));
    chart
        .draw_series(
            val.iter()
                .map(|&(s, v)| Circle::new((s, v), 3, orange.filled())),
        )
        .map_err(|e| err(e.to_string()))?;
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| err(e.to_string()))?;
    root.present().map_err(|e| err(e.to_string()))
}

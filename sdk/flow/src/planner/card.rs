//! What the planner takes from a model card so that it plans as the model was trained: the BEV
//! raster ([`bev_spec`]) and the spacing of the poses ([`check_dt`]).

use super::PlannerError;
use crate::card::ModelCard;
use human2nav_core::bev::BevSpec;
use human2nav_core::human2nav::Human2NavSettings;

/// Where a planner's BEV raster came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BevOrigin {
    /// The model card's `[bev]` table (written by `human2nav train`; its cells are checked
    /// against the network's input size when the card is loaded).
    Card,
    /// A card without `[bev]` (written before the table existed): the cell size is read from
    /// its training record.
    Record,
    /// Neither (an untrained model): the data pipeline's default cell size.
    Default,
}

/// The BEV raster the model was trained on: the card's `[bev]` table; for older cards the
/// network's input size `card.net.bev_cells` with the cell size of the training record
/// ("... cells of 0.3 m ..."), or the data pipeline's default when there is none.
pub fn bev_spec(card: &ModelCard) -> (BevSpec, BevOrigin) {
    if let Some(bev) = card.bev {
        return (bev, BevOrigin::Card);
    }
    let cells = card.net.bev_cells;
    let from_record = card
        .training
        .as_ref()
        .and_then(|t| resolution_from_record(&t.data));
    match from_record {
        Some(resolution) => (BevSpec { cells, resolution }, BevOrigin::Record),
        None => (
            BevSpec {
                cells,
                ..BevSpec::default()
            },
            BevOrigin::Default,
        ),
    }
}

/// The number after `marker` in a training record, if it is a positive finite number.
fn number_after(data: &str, marker: &str) -> Option<f64> {
    let (_, rest) = data.split_once(marker)?;
    let number: String = rest
        .chars()
        .take_while(|c| c.is_ascii_digit() || *c == '.' || *c == 'e' || *c == '-')
        .collect();
    number
        .parse::<f64>()
        .ok()
        .filter(|r| r.is_finite() && *r > 0.0)
}

/// The number after `cells of` in a training record, if it is a positive finite length.
pub(super) fn resolution_from_record(data: &str) -> Option<f64> {
    number_after(data, "cells of ")
}

/// Spacing (s) of the poses of every tuple the data pipeline writes: `data.toml` refuses any
/// other `resample.dt`, so every model is trained at it.
pub const TRAINING_DT: f64 = 0.1;

/// The spacing (s) of the poses a model was trained on: the training record's "... poses at
/// 0.1 s", else [`TRAINING_DT`].
pub fn trained_dt(card: &ModelCard) -> f64 {
    card.training
        .as_ref()
        .and_then(|t| number_after(&t.data, "poses at "))
        .unwrap_or(TRAINING_DT)
}

/// Refuses a planner `dt` other than the one the model was trained on: the network's
/// velocities are per training step, so poses spaced at another `dt` would replay the learnt
/// motion faster or slower than the people it learnt from (`human2nav.dt = 0.4` made every
/// sample four times as fast).
pub fn check_dt(card: &ModelCard, settings: &Human2NavSettings) -> Result<(), PlannerError> {
    let trained = trained_dt(card);
    if (settings.dt - trained).abs() > 1e-9 {
        return Err(PlannerError::Setting {
            field: "human2nav.dt".into(),
            message: format!(
                "{} s, but the model `{}` was trained on poses {trained} s apart; set \
                 human2nav.dt = {trained}",
                settings.dt, card.name
            ),
        });
    }
    Ok(())
}

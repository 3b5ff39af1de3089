//! The model's files and the encoding of its inputs, shared by both backends and by training.
//!
//! A model folder holds a card ([`CARD_FILE`], [`crate::card::ModelCard`]) and its weights
//! ([`WEIGHTS_FILE`], safetensors). [`normalise_condition`], [`crowd_points`] and
//! [`trajectory_features`] turn a condition and poses into what the network reads; training,
//! the libtorch model and the native one all go through them, so they see the same inputs.
//!
//! [`CfmModel`], the libtorch implementation of core's [`human2nav_core::FlowModel`] (and the
//! one training updates), is here with the `torch` feature; [`crate::NativeCfm`] runs the
//! same weights without libtorch.

use crate::card::ModelCard;
use crate::config::{CrowdConfig, Normalisation};
use human2nav_core::bev::BevSpec;
use human2nav_core::flow::{FlowCondition, FlowError};

#[cfg(feature = "torch")]
mod cfm_model;
#[cfg(feature = "torch")]
pub use cfm_model::CfmModel;
#[cfg(feature = "torch")]
pub(crate) use cfm_model::{read_safetensors, write_safetensors};

/// The model card's file name inside a model folder (TOML, [`crate::card::ModelCard`]).
pub const CARD_FILE: &str = "model.toml";
/// The weights' file name inside a model folder (safetensors).
pub const WEIGHTS_FILE: &str = "model.safetensors";
/// Largest weights file read (1 GiB; the shipped model's is 1.5 MB).
pub const MAX_WEIGHTS_BYTES: u64 = 1 << 30;

/// Writes the normalised condition of one example: the raster with its velocity channels
/// divided by the speed scale into `bev_out` (`3·H·W`), and
/// `[g_x/goal_scale, g_y/goal_scale, v_x/speed_scale, v_y/speed_scale]` into `goal_out` (the
/// goal zero for a model that is not [`Normalisation::goal_conditioned`], the velocity zero for
/// one that is not [`Normalisation::velocity_conditioned`]).
///
/// Training and inference both go through this function, so the network sees the same inputs.
pub fn normalise_condition(
    norm: &Normalisation,
    bev: &[f32],
    goal: [f64; 2],
    velocity: [f64; 2],
    bev_out: &mut [f32],
    goal_out: &mut [f32],
) {
    let plane = bev.len() / 3;
    let inv_speed = (1.0 / norm.speed_scale) as f32;
    bev_out[..plane].copy_from_slice(&bev[..plane]);
    for (o, &b) in bev_out[plane..].iter_mut().zip(&bev[plane..]) {
        *o = b * inv_speed;
    }
    let goal = if norm.goal_conditioned {
        goal
    } else {
        [0.0; 2]
    };
    goal_out[0] = (goal[0] / norm.goal_scale) as f32;
    goal_out[1] = (goal[1] / norm.goal_scale) as f32;
    let velocity = if norm.velocity_conditioned {
        velocity
    } else {
        [0.0; 2]
    };
    goal_out[2] = (velocity[0] / norm.speed_scale) as f32;
    goal_out[3] = (velocity[1] / norm.speed_scale) as f32;
}

/// The normalised raster (`3·H·W`) and goal/velocity features of a planning condition
/// ([`normalise_condition`]), or a shape error when its raster is not the network's.
pub(crate) fn planning_condition(
    card: &ModelCard,
    cond: &FlowCondition,
) -> Result<(Vec<f32>, [f32; 4]), FlowError> {
    let len = card.net.bev_len();
    if cond.bev.len() != len {
        let cells = card.net.bev_cells;
        return Err(FlowError::Shape(format!(
            "BEV raster has {} values, the model expects 3×{cells}×{cells} = {len}",
            cond.bev.len()
        )));
    }
    let mut bev = vec![0f32; len];
    let mut gv = [0f32; 4];
    normalise_condition(
        &card.normalisation,
        &cond.bev,
        cond.goal,
        cond.velocity,
        &mut bev,
        &mut gv,
    );
    Ok((bev, gv))
}

/// Writes the crowd points of one raster (`[3, H, W]`, velocities in m/s as rasterized) into
/// `out` (`crowd.points × 5`): the occupied cells nearest the ego (ties by cell order), each
/// as `[x/s, y/s, v_x/s, v_y/s, 1]` with `(x, y)` the cell's centre in the ego frame and
/// `(v_x, v_y)` its velocity, so that `position + velocity·τ` is the cell carried on for `τ`
/// seconds in the network's units; unused rows are zero (`present = 0`).
///
/// Training and inference both go through this function.
pub fn crowd_points(
    crowd: &CrowdConfig,
    norm: &Normalisation,
    cells: usize,
    bev: &[f32],
    out: &mut [f32],
) {
    let spec = BevSpec {
        cells,
        resolution: crowd.cell,
    };
    let plane = cells * cells;
    // (distance from the ego, cell index, cell centre), nearest first, ties by cell order.
    let mut occupied: Vec<(f64, usize, [f64; 2])> = bev[..plane]
        .iter()
        .enumerate()
        .filter(|(_, o)| **o > 0.5)
        .map(|(i, _)| {
            let c = spec.cell_center(i / cells, i % cells);
            (c[0].hypot(c[1]), i, c)
        })
        .collect();
    let order = |a: &(f64, usize, [f64; 2]), b: &(f64, usize, [f64; 2])| {
        a.0.total_cmp(&b.0).then(a.1.cmp(&b.1))
    };
    let n = crowd.points.min(occupied.len());
    if n < occupied.len() {
        occupied.select_nth_unstable_by(n, order);
        occupied.truncate(n);
    }
    occupied.sort_unstable_by(order);
    out.fill(0.0);
    let inv = 1.0 / norm.position_scale;
    for (row, &(_, i, [x, y])) in out.chunks_exact_mut(5).zip(&occupied) {
        row[0] = (x * inv) as f32;
        row[1] = (y * inv) as f32;
        row[2] = (f64::from(bev[plane + i]) * inv) as f32;
        row[3] = (f64::from(bev[2 * plane + i]) * inv) as f32;
        row[4] = 1.0;
    }
}

/// Trajectory features of normalised poses (flat `[T, 3]`, translations already divided by
/// `s`), written channel-major `[5, T]` into `out`: `x, y, cos θ, sin θ, (i + 1)/T`.
pub fn trajectory_features(poses: &[f64], out: &mut [f32]) {
    let t = poses.len() / 3;
    for (i, p) in poses.chunks_exact(3).enumerate() {
        out[i] = p[0] as f32;
        out[t + i] = p[1] as f32;
        out[2 * t + i] = p[2].cos() as f32;
        out[3 * t + i] = p[2].sin() as f32;
        out[4 * t + i] = (i + 1) as f32 / t as f32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn encoded(norm: &Normalisation) -> ([f32; 12], [f32; 4]) {
        let bev = [1.0, 0.0, 0.0, 1.0, 2.6, 0.0, 0.0, -2.6, 0.0, 1.3, 0.0, 0.0];
        let (mut bev_out, mut goal_out) = ([0.0; 12], [0.0; 4]);
        normalise_condition(
            norm,
            &bev,
            [4.0, -2.0],
            [1.3, 0.65],
            &mut bev_out,
            &mut goal_out,
        );
        (bev_out, goal_out)
    }

    #[test]
    fn the_condition_is_scaled_and_the_inputs_a_model_does_not_see_are_zero() {
        let norm = Normalisation {
            goal_scale: 2.0,
            speed_scale: 1.3,
            ..Normalisation::default()
        };
        let (bev, goal) = encoded(&norm);
        assert_eq!(goal, [2.0, -1.0, 1.0, 0.5]);
        assert_eq!(bev[..4], [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(bev[4..8], [2.0, 0.0, 0.0, -2.0]);

        let blind = |goal_conditioned, velocity_conditioned| Normalisation {
            goal_conditioned,
            velocity_conditioned,
            ..norm.clone()
        };
        assert_eq!(encoded(&blind(false, true)).1, [0.0, 0.0, 1.0, 0.5]);
        assert_eq!(encoded(&blind(true, false)).1, [2.0, -1.0, 0.0, 0.0]);
        // The raster is the same whatever the model does not see.
        assert_eq!(encoded(&blind(false, false)).0, bev);
    }
}

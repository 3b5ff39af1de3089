//! Architecture hyper-parameters and the trajectory normalisation stored with a model.

use crate::error::CfmError;
use serde::{Deserialize, Serialize};

/// Hyper-parameters of the conditional 1-D temporal U-Net ([`crate::net::CondUnet1d`]).
///
/// Defaults give about 0.6 M parameters, sized to train on two CPU cores in well under an hour
/// and to plan in real time (see the model card for measured numbers).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetConfig {
    /// Waypoints per trajectory `T`. Default 32 (3.2 s at 0.1 s).
    pub horizon: usize,
    /// Cells per side of the `[3, H, W]` BEV raster (`H = W`). Default 32.
    pub bev_cells: usize,
    /// Channels of the U-Net levels; one level per entry, each but the last halves the time
    /// axis. Default `[32, 64]` (two levels over T = 32 and 16).
    pub down_dims: Vec<usize>,
    /// Residual blocks per U-Net level (down and up). Default 1 (Diffusion Policy uses 2).
    pub blocks_per_level: usize,
    /// Residual blocks at the coarsest resolution. Default 1 (Diffusion Policy uses 2).
    pub mid_blocks: usize,
    /// Temporal kernel size of the residual convolutions (odd). Default 3.
    pub kernel_size: usize,
    /// Groups of every GroupNorm. Default 8.
    pub n_groups: usize,
    /// Activation after every normalisation. Default SiLU.
    pub activation: Activation,
    /// Width of the sinusoidal flow-time embedding. Default 64.
    pub time_embed_dim: usize,
    /// Channels of the three stride-2 convolutions of the BEV encoder. Default `[16, 32, 64]`.
    pub bev_channels: [usize; 3],
    /// Width of the BEV embedding. Default 128.
    pub bev_embed_dim: usize,
    /// Width of the goal-and-velocity embedding. Default 64.
    pub goal_embed_dim: usize,
    /// The per-waypoint crowd pathway ([`CrowdConfig`]); absent (the default, and every model
    /// trained before it existed): the crowd reaches the U-Net only through the pooled BEV
    /// embedding's FiLM.
    pub crowd: Option<CrowdConfig>,
}

/// The per-waypoint crowd pathway of [`crate::net::CondUnet1d`].
///
/// The BEV embedding conditions the U-Net through FiLM, a per-channel scale and shift that is
/// the same at every waypoint: it can say "there are people around" but not "this waypoint
/// is 0.4 m from where that person will be". The pathway gives the network that relation.
/// The raster's occupied cells nearest the ego are read as points, each with its cell's
/// velocity ([`crate::model::crowd_points`]); at every waypoint `i` of the trajectory being
/// integrated, each point is carried on at its velocity to the waypoint's time
/// `(i + 1)·step` and expressed in the waypoint's own frame (offset, distance, velocity); a
/// shared two-layer MLP embeds every (point, waypoint) pair and a max over the points gives
/// `width` features per waypoint, which join the trajectory's input channels. It reads the
/// same raster as the BEV encoder (no other input), so everything that builds a raster, the
/// planner and the crowd-hidden probe included, feeds it unchanged.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CrowdConfig {
    /// Occupied raster cells read per condition, nearest to the ego first. Default 40 (about
    /// ten people: a pedestrian's disc covers three to five cells of 0.3 m).
    pub points: usize,
    /// Features per waypoint (the MLP's width). Default 32.
    pub width: usize,
    /// Edge of one raster cell, metres: the model card's `bev.resolution` (checked when the
    /// model is loaded and when training starts). Default 0.3.
    pub cell: f64,
    /// Seconds between waypoints. Default 0.1.
    pub step: f64,
}

impl Default for CrowdConfig {
    fn default() -> Self {
        Self {
            points: 40,
            width: 32,
            cell: 0.3,
            step: 0.1,
        }
    }
}

impl CrowdConfig {
    /// Checks the pathway can be built.
    pub fn validate(&self) -> Result<(), CfmError> {
        if self.points == 0 || self.points > 1024 {
            return Err(CfmError::option(
                "net.crowd.points",
                "must be between 1 and 1024",
            ));
        }
        if self.width == 0 || self.width > 1024 {
            return Err(CfmError::option(
                "net.crowd.width",
                "must be between 1 and 1024",
            ));
        }
        if !(self.cell.is_finite() && self.cell > 0.0) {
            return Err(CfmError::option("net.crowd.cell", "must be finite and > 0"));
        }
        if !(self.step.is_finite() && self.step > 0.0) {
            return Err(CfmError::option("net.crowd.step", "must be finite and > 0"));
        }
        Ok(())
    }
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            horizon: 32,
            bev_cells: 32,
            down_dims: vec![32, 64],
            blocks_per_level: 1,
            mid_blocks: 1,
            kernel_size: 3,
            n_groups: 8,
            activation: Activation::Silu,
            time_embed_dim: 64,
            bev_channels: [16, 32, 64],
            bev_embed_dim: 128,
            goal_embed_dim: 64,
            crowd: None,
        }
    }
}

/// Activation function of the network.
///
/// Diffusion Policy uses Mish. With the libtorch CPU build used here Mish (through `tanh`) is
/// about eight times slower than SiLU, whose shape is nearly the same (both are smooth,
/// non-monotone near zero and linear for large inputs), so SiLU is the default.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Activation {
    /// SiLU, `x·σ(x)` (the default).
    #[default]
    Silu,
    /// Mish, `x·tanh(softplus(x))`, as in Diffusion Policy.
    Mish,
}

impl NetConfig {
    /// Checks the hyper-parameters describe a buildable network.
    pub fn validate(&self) -> Result<(), CfmError> {
        if self.horizon == 0 {
            return Err(CfmError::option("net.horizon", "must be positive"));
        }
        if self.down_dims.is_empty() {
            return Err(CfmError::option(
                "net.down_dims",
                "needs at least one level",
            ));
        }
        let levels = self.down_dims.len();
        if self.horizon % (1 << (levels - 1)) != 0 {
            return Err(CfmError::option(
                "net.down_dims",
                format!(
                    "{levels} levels halve the horizon {} times, which must divide it",
                    levels - 1
                ),
            ));
        }
        if self.n_groups == 0 {
            return Err(CfmError::option("net.n_groups", "must be positive"));
        }
        for &d in &self.down_dims {
            if d == 0 || d % self.n_groups != 0 {
                return Err(CfmError::option(
                    "net.down_dims",
                    format!(
                        "{d} is not a positive multiple of n_groups = {}",
                        self.n_groups
                    ),
                ));
            }
        }
        for &d in &self.bev_channels {
            if d == 0 || d % self.n_groups != 0 {
                return Err(CfmError::option(
                    "net.bev_channels",
                    format!(
                        "{d} is not a positive multiple of n_groups = {}",
                        self.n_groups
                    ),
                ));
            }
        }
        if self.blocks_per_level == 0 {
            return Err(CfmError::option(
                "net.blocks_per_level",
                "must be at least 1",
            ));
        }
        if self.kernel_size == 0 || self.kernel_size % 2 == 0 {
            return Err(CfmError::option("net.kernel_size", "must be odd"));
        }
        if self.time_embed_dim < 4 || self.time_embed_dim % 2 != 0 {
            return Err(CfmError::option(
                "net.time_embed_dim",
                "must be even and at least 4",
            ));
        }
        if self.bev_cells < 8 {
            return Err(CfmError::option("net.bev_cells", "must be at least 8"));
        }
        if self.bev_embed_dim == 0 || self.goal_embed_dim == 0 {
            return Err(CfmError::option("net.*_embed_dim", "must be positive"));
        }
        if let Some(c) = &self.crowd {
            c.validate()?;
        }
        Ok(())
    }

    /// Input channels of the U-Net: the trajectory's own and the crowd pathway's.
    pub fn unet_in_channels(&self) -> usize {
        crate::net::TRAJ_CHANNELS as usize + self.crowd.as_ref().map_or(0, |c| c.width)
    }

    /// Values of one condition's crowd points, `points × 5` (0 without the pathway).
    pub fn crowd_len(&self) -> usize {
        self.crowd
            .as_ref()
            .map_or(0, |c| c.points * crate::net::CROWD_FEATURES as usize)
    }

    /// Length of one BEV raster, `3·H·W`.
    pub fn bev_len(&self) -> usize {
        3 * self.bev_cells * self.bev_cells
    }

    /// Width of the FiLM conditioning vector: time + BEV + goal embeddings.
    pub fn cond_dim(&self) -> usize {
        self.time_embed_dim + self.bev_embed_dim + self.goal_embed_dim
    }
}

/// The normalisation a model applies between metric units and network units.
///
/// Translations are divided by `position_scale` (`s`). Because `(x, y, θ) ↦ (x/s, y/s, θ)` is
/// an automorphism of SE(2) that commutes with `exp`/`log`, the flow is learned in these
/// normalised coordinates and maps exactly onto a flow in metres: a normalised velocity
/// `(v_x, v_y, ω)` is `(s·v_x, s·v_y, ω)` in metric units. The source distribution is the
/// paper's `ξ0 ~ N(0, I)` in normalised coordinates, i.e. `N(0, diag(s², s², 1))` in metres
/// and radians ([`Normalisation::source_std`]).
///
/// The network's output is additionally standardised per component by `velocity_std` (the
/// standard deviation of the training targets in normalised coordinates), and the goal and
/// the velocities of the conditioning (goal, ego velocity, BEV velocity channels) are divided
/// by `goal_scale` and `speed_scale`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normalisation {
    /// `s`, metres: root-mean-square distance of the future waypoints from the current pose.
    pub position_scale: f64,
    /// Standard deviation of the target velocity `log(x0⁻¹x1)` per component
    /// `(v_x, v_y, ω)`, in normalised units.
    pub velocity_std: [f64; 3],
    /// Goal distance scale, metres (root mean square over the training set).
    pub goal_scale: f64,
    /// Speed scale, m/s (root-mean-square ego speed over the training set).
    pub speed_scale: f64,
    /// Whether the network sees the goal. `false`: the goal input is always zero, in training
    /// and at inference, so the model generates where a walker goes from its velocity and the
    /// scene alone: a goal-free, multimodal predictor of people (`train.goal = false`).
    /// Default true.
    #[serde(default = "conditioned_default")]
    pub goal_conditioned: bool,
    /// Whether the network sees the ego velocity. `false`: the velocity input is always zero,
    /// in training and at inference, so the model has only its heading (the frame), the goal
    /// and the scene to go on (`train.velocity = false`; a lever of the model issue,
    /// docs/experiments/2026-12-07-velocity-and-dose.md). Default true.
    #[serde(default = "conditioned_default")]
    pub velocity_conditioned: bool,
}

fn conditioned_default() -> bool {
    true
}

impl Default for Normalisation {
    fn default() -> Self {
        Self {
            position_scale: 1.0,
            velocity_std: [1.0; 3],
            goal_scale: 1.0,
            speed_scale: 1.0,
            goal_conditioned: true,
            velocity_conditioned: true,
        }
    }
}

impl Normalisation {
    /// Checks every scale is finite and positive.
    pub fn validate(&self) -> Result<(), CfmError> {
        let ok = |v: f64| v.is_finite() && v > 0.0;
        if !ok(self.position_scale) {
            return Err(CfmError::option(
                "normalisation.position_scale",
                "must be finite and > 0",
            ));
        }
        if !self.velocity_std.iter().all(|&v| ok(v)) {
            return Err(CfmError::option(
                "normalisation.velocity_std",
                "must be finite and > 0",
            ));
        }
        if !ok(self.goal_scale) {
            return Err(CfmError::option(
                "normalisation.goal_scale",
                "must be finite and > 0",
            ));
        }
        if !ok(self.speed_scale) {
            return Err(CfmError::option(
                "normalisation.speed_scale",
                "must be finite and > 0",
            ));
        }
        Ok(())
    }

    /// `[s, s, 1]`: the source's standard deviation in metres and radians.
    pub fn source_std(&self) -> [f64; 3] {
        [self.position_scale, self.position_scale, 1.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_validate() {
        NetConfig::default().validate().unwrap();
        Normalisation::default().validate().unwrap();
    }

    /// `n_groups = 0` is refused by name before any division by it (training and model loading
    /// both validate the net first).
    #[test]
    fn zero_groups_is_an_error_not_a_panic() {
        let cfg = NetConfig {
            n_groups: 0,
            ..NetConfig::default()
        };
        let err = cfg.validate().unwrap_err().to_string();
        assert!(err.contains("net.n_groups"), "{err}");
    }

    #[test]
    fn rejects_bad_levels_and_unknown_fields() {
        let cfg = NetConfig {
            horizon: 30,
            down_dims: vec![16, 32, 64],
            ..NetConfig::default()
        };
        assert!(matches!(
            cfg.validate(),
            Err(CfmError::Option {
                field: "net.down_dims",
                ..
            })
        ));
        let cfg = NetConfig {
            kernel_size: 4,
            ..NetConfig::default()
        };
        assert!(matches!(
            cfg.validate(),
            Err(CfmError::Option {
                field: "net.kernel_size",
                ..
            })
        ));
        assert!(toml::from_str::<NetConfig>("horizon = 32\nwidth = 3").is_err());
        let n = Normalisation {
            goal_scale: 0.0,
            ..Normalisation::default()
        };
        assert!(n.validate().is_err());
    }
}

//! A robot's side of the planner: its profile and Φ, and [`RobotPlanner`], the planner built
//! from a profile and a model folder.

use super::{
    Backend, BevOrigin, PlannerConfig, PlannerError, PlannerModel, PredictionModel, bev_spec,
    check_dt, load_model,
};
use human2nav_core::Limits;
use human2nav_core::bev::BevSpec;
use human2nav_core::constraint::Phi;
use human2nav_core::forecast::CrowdPredictor;
use human2nav_core::human2nav::{Human2Nav, Human2NavSettings, RobotModel};
use human2nav_core::robot::RobotProfile;
use human2nav_plugin::PluginHost;
use std::path::Path;

/// Φ of a robot: the profile's built-in soft-margin terms (Eq. 8-9, weighted by its
/// `[cost]` table) plus every `[[constraint]]` plugin term it names.
pub fn robot_phi(profile: &RobotProfile) -> Result<Phi, PlannerError> {
    PluginHost::new()
        .phi(profile)
        .map_err(|e| PlannerError::Plugin {
            path: profile.source.clone(),
            message: e.to_string(),
        })
}

/// What the planner needs to know about a robot, from its profile and its Φ.
pub fn robot_model(profile: &RobotProfile, phi: Phi) -> RobotModel {
    RobotModel {
        limits: profile.limits,
        footprint: profile.footprint_shapes.clone(),
        phi,
    }
}

/// Loads a robot profile, naming the file in the error, with its limits completed by its
/// embodiment (a plugin embodiment's coupled limit, see [`PluginHost::robot_embodiment`]).
pub fn load_profile(path: &Path) -> Result<RobotProfile, PlannerError> {
    let mut profile = RobotProfile::load(path).map_err(|e| PlannerError::Profile {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    PluginHost::new()
        .robot_embodiment(&mut profile)
        .map_err(|e| PlannerError::Plugin {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
    Ok(profile)
}

/// A Human2Nav planner for one robot, with what it was built from.
#[derive(Debug)]
pub struct RobotPlanner {
    /// The robot.
    pub profile: RobotProfile,
    /// The BEV raster the planner rasterises (the model's training raster).
    pub bev: BevSpec,
    /// Where `bev`'s cell size came from.
    pub bev_origin: BevOrigin,
    /// The planner.
    pub planner: Human2Nav<PlannerModel>,
}

impl RobotPlanner {
    /// A planner for `profile` with an already loaded `model`: Φ from the profile (built-in and
    /// plugin terms), the BEV raster from the model card.
    pub fn new(
        profile: RobotProfile,
        model: impl Into<PlannerModel>,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        let model = model.into();
        check_dt(model.card(), &settings)?;
        let phi = robot_phi(&profile)?;
        let (bev, bev_origin) = bev_spec(model.card());
        let planner = Human2Nav::new(model, robot_model(&profile, phi), bev, settings)?;
        Ok(Self {
            profile,
            bev,
            bev_origin,
            planner,
        })
    }

    /// Loads the robot profile at `robot_toml` and the model folder `model_dir` (run by the
    /// native backend), and builds the planner.
    ///
    /// ```
    /// use human2nav_core::{Observation, Planner};
    /// use human2nav_flow::planner::{PlannerConfig, RobotPlanner};
    ///
    /// let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    /// let config = PlannerConfig::load(&root.join("sdk/configs/planner.toml"))?;
    /// let robot = root.join("robots/diablo/robot.toml");
    /// let mut diablo = RobotPlanner::load(&robot, &config.model_dir(&root), config.human2nav)?;
    /// // The robot at rest at the origin, its goal 4 m ahead, nobody around.
    /// let obs = Observation { goal: [4.0, 0.0], ..Observation::default() };
    /// let plan = diablo.planner.plan(&obs)?;
    /// assert!(plan.poses.len() > 1 && plan.poses.last().is_some_and(|p| p.x > 0.0));
    /// # Ok::<(), Box<dyn std::error::Error>>(())
    /// ```
    pub fn load(
        robot_toml: &Path,
        model_dir: &Path,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        Self::load_with(robot_toml, model_dir, Backend::Native, settings)
    }

    /// [`Self::load`] with the backend chosen.
    pub fn load_with(
        robot_toml: &Path,
        model_dir: &Path,
        backend: Backend,
        settings: Human2NavSettings,
    ) -> Result<Self, PlannerError> {
        let profile = load_profile(robot_toml)?;
        let model = load_model(model_dir, backend)?;
        Self::new(profile, model, settings)
    }

    /// The robot's hard limits.
    pub fn limits(&self) -> &Limits {
        &self.profile.limits
    }

    /// The same planner with the prediction `cfg` names ([`PredictionConfig`]; unchanged when
    /// it names no model), relative paths from `workspace`.
    ///
    /// [`PredictionConfig`]: super::PredictionConfig
    pub fn with_prediction(
        self,
        cfg: &PlannerConfig,
        workspace: &Path,
    ) -> Result<Self, PlannerError> {
        Ok(match PredictionModel::load(cfg, workspace)? {
            Some(m) => self.with_predictor(m.predictor()?),
            None => self,
        })
    }

    /// The same planner with its selection scoring against `predictor`'s forecasts
    /// ([`Human2Nav::with_predictor`]).
    pub fn with_predictor(self, predictor: Box<dyn CrowdPredictor>) -> Self {
        Self {
            planner: self.planner.with_predictor(predictor),
            ..self
        }
    }
}

//! Observations through a loaded plugin: random robot and pedestrian states (NaN, infinities,
//! 1e300, subnormals, raw bit patterns) and random counts, fed through the plugin host to the
//! shipped `orca` planner plugin and the `personal_space` constraint plugin. The host must
//! return an error or a finite result; the plugins are loaded once per process.
//!
//! The libraries are looked up beside the running executable (`target/<profile>/`, or its
//! parent for a test binary in `deps/`), or in `HUMAN2NAV_FUZZ_PLUGIN_DIR`: build the workspace
//! first (`cargo build --workspace`).

use crate::{Scratch, Target};
use human2nav_core::constraint::{ConstraintContext, ConstraintTerm, TrajBatch};
use human2nav_core::obstacle::Obstacle;
use human2nav_core::{AgentState, Limits, Observation, Planner, Pose2, Twist2};
use human2nav_plugin::resolve::resolve_library_path;
use human2nav_plugin::{PluginConstraint, PluginHost, PluginPlanner};
use std::path::PathBuf;
use std::sync::{Mutex, OnceLock};

pub(crate) fn targets() -> Vec<Target> {
    vec![Target {
        name: "plugin_observation",
        covers: "random observations (states with NaN/inf/1e300, 0 to 5000 agents with \
                     histories, obstacles) through the plugin host to the shipped `orca` \
                     planner plugin, and random trajectory batches with those agents to the \
                     `personal_space` constraint plugin: an error or a finite plan / cost",
        seeds: || {
            vec![
                vec![0u8; 64],
                (0u8..=255).collect(),
                (0u8..=255).rev().cycle().take(700).collect(),
            ]
        },
        exec: plugin_observation,
    }]
}

/// The directory holding the plugin libraries (module docs).
fn plugin_dir() -> PathBuf {
    if let Some(dir) = std::env::var_os("HUMAN2NAV_FUZZ_PLUGIN_DIR") {
        return PathBuf::from(dir);
    }
    let exe = std::env::current_exe().unwrap_or_default();
    let here = exe.parent().map(PathBuf::from).unwrap_or_default();
    if here.file_name().is_some_and(|n| n == "deps") {
        here.parent().map(PathBuf::from).unwrap_or(here)
    } else {
        here
    }
}

fn library(stem: &str) -> PathBuf {
    let path = plugin_dir().join(stem);
    match resolve_library_path(&path) {
        Ok(p) => p,
        Err(e) => panic!(
            "fuzz target plugin_observation: {e} (build the workspace first, `cargo build \
             --workspace`, or set HUMAN2NAV_FUZZ_PLUGIN_DIR)"
        ),
    }
}

struct Loaded {
    host: PluginHost,
    planner: PluginPlanner,
    constraint: PluginConstraint,
}

fn loaded() -> &'static Mutex<Loaded> {
    static LOADED: OnceLock<Mutex<Loaded>> = OnceLock::new();
    LOADED.get_or_init(|| {
        let host = PluginHost::new();
        let planner = fresh_planner(&host);
        let constraint = fresh_constraint(&host);
        Mutex::new(Loaded {
            host,
            planner,
            constraint,
        })
    })
}

fn fresh_planner(host: &PluginHost) -> PluginPlanner {
    match host.planner(&library("human2nav_orca"), "orca", "", None) {
        Ok(p) => p,
        Err(e) => panic!("the shipped orca plugin does not load: {e}"),
    }
}

fn fresh_constraint(host: &PluginHost) -> PluginConstraint {
    match host.constraint(
        &library("human2nav_personal_space"),
        "personal_space",
        "",
        None,
    ) {
        Ok(c) => c,
        Err(e) => panic!("the shipped personal_space plugin does not load: {e}"),
    }
}

/// Reads the input as a stream of choices; past its end, zeros.
pub(crate) struct Draw<'a> {
    pub(crate) b: &'a [u8],
    pub(crate) i: usize,
    /// One value in `hostile` is an extreme (NaN, inf, 1e300, raw bits, ...); 0: none. Set per
    /// input, so that some observations are entirely ordinary and reach the plugin.
    pub(crate) hostile: u8,
}

impl Draw<'_> {
    pub(crate) fn u8(&mut self) -> u8 {
        let v = self.b.get(self.i).copied().unwrap_or(0);
        self.i += 1;
        v
    }
    pub(crate) fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }
    pub(crate) fn u64(&mut self) -> u64 {
        (0..8).fold(0u64, |v, _| (v << 8) | u64::from(self.u8()))
    }
    /// A value: ordinary (metres, m/s, within ±16), or (one in `hostile`) an extreme.
    pub(crate) fn f64(&mut self) -> f64 {
        let extreme = self.hostile != 0 && self.u8() % self.hostile == 0;
        if !extreme {
            return (f64::from(self.u16()) - 32768.0) / 2048.0;
        }
        match self.u8() % 8 {
            0 => f64::NAN,
            1 => f64::INFINITY,
            2 => f64::NEG_INFINITY,
            3 => 1e300 * if self.u8() % 2 == 0 { 1.0 } else { -1.0 },
            4 => f64::MIN_POSITIVE / 4.0,
            5 => -0.0,
            6 => 1e6 + f64::from(self.u8()),
            _ => f64::from_bits(self.u64()),
        }
    }
    /// A count: mostly small, sometimes large.
    pub(crate) fn count(&mut self, small: usize, large: usize) -> usize {
        match self.u8() % 8 {
            0 => 0,
            1 => usize::from(self.u16()) % (large + 1),
            _ => usize::from(self.u8()) % (small + 1),
        }
    }
}

fn observation(d: &mut Draw<'_>) -> Observation {
    let time = d.f64();
    let ego = Pose2::new(d.f64(), d.f64(), d.f64());
    let ego_velocity = Twist2::new(d.f64(), d.f64(), d.f64());
    let goal = [d.f64(), d.f64()];
    let n = d.count(12, 5000);
    let agents = (0..n)
        .map(|k| {
            let h = d.count(4, 200);
            AgentState {
                id: if d.u8() % 8 == 0 { 7 } else { k as u64 },
                position: [d.f64(), d.f64()],
                velocity: [d.f64(), d.f64()],
                radius: d.f64(),
                history: (0..h).map(|_| [d.f64(), d.f64()]).collect(),
            }
        })
        .collect();
    let obstacles = (0..d.count(3, 40))
        .map(|_| match d.u8() % 3 {
            0 => Obstacle::Circle {
                center: [d.f64(), d.f64()],
                radius: d.f64(),
            },
            1 => Obstacle::Segment {
                a: [d.f64(), d.f64()],
                b: [d.f64(), d.f64()],
            },
            _ => Obstacle::Polygon {
                vertices: (0..d.count(5, 50)).map(|_| [d.f64(), d.f64()]).collect(),
            },
        })
        .collect();
    Observation {
        time,
        ego,
        ego_velocity,
        goal,
        agents,
        obstacles,
        ..Default::default()
    }
}

/// How far one input got: whether the planner returned a plan and the constraint evaluated
/// (rather than the host refusing the input). The bounded test checks inputs get that far.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reached {
    /// The planner's error, when it returned one.
    pub plan_error: Option<String>,
    /// The orca plugin returned a (finite) plan.
    pub planned: bool,
    /// The personal_space plugin returned a cost and gradient.
    pub evaluated: bool,
}

fn plugin_observation(_: &Scratch, input: &[u8]) {
    let _ = run_observation(input);
}

/// Feeds one input to both plugins (module docs); panics on a crash-class outcome (a NaN or
/// non-finite plan, NaN from finite inputs, wrong output sizes accepted).
pub fn run_observation(input: &[u8]) -> Reached {
    let mut reached = Reached::default();
    let hostile = [0, 0, 64, 16, 4, 1][usize::from(input.first().copied().unwrap_or(0) % 6)];
    let mut d = Draw {
        b: input.get(1..).unwrap_or(&[]),
        i: 0,
        hostile,
    };
    let obs = observation(&mut d);
    let mut guard = loaded().lock().unwrap_or_else(|p| p.into_inner());
    let l = &mut *guard;
    if l.planner.is_poisoned() {
        l.planner = fresh_planner(&l.host);
    }
    if d.u8() % 16 == 0 {
        l.planner.reset();
    }
    match l.planner.plan(&obs) {
        Ok(plan) => {
            assert!(
                plan.is_finite() && !plan.poses.is_empty(),
                "the host returned an empty or non-finite plan: {plan:?}"
            );
            reached.planned = true;
        }
        Err(e) => {
            // The export layer turns a panic into an error and poisons the instance: for a
            // shipped plugin that is a bug all the same.
            let message = e.to_string();
            assert!(
                !message.contains("panicked:"),
                "the orca plugin panicked: {message}"
            );
            reached.plan_error = Some(message);
        }
    }

    // The same agents around a batch of trajectories for the constraint plugin.
    if l.constraint.is_poisoned() {
        l.constraint = fresh_constraint(&l.host);
    }
    let batch = d.count(4, 64);
    let horizon = d.count(40, 400);
    let values = batch * horizon * 3;
    let data: Vec<f64> = (0..values).map(|_| d.f64()).collect();
    let limits = Limits {
        v_max: d.f64(),
        v_reverse_max: 0.4,
        a_max: d.f64(),
        omega_max: 1.5,
        kappa_max: if d.u8() % 2 == 0 { None } else { Some(d.f64()) },
        lateral_speed_max: 0.05,
        coupled: None,
    };
    let ctx = ConstraintContext {
        dt: d.f64(),
        limits: &limits,
        initial_velocity: obs.ego_velocity,
        agents: &obs.agents,
        scene: Default::default(),
    };
    // Outputs of the right size, or (one call in eight) of a wrong one.
    let wrong = usize::from(d.u8() % 8 == 0);
    let mut cost = vec![0.0; batch + wrong];
    let mut grad = vec![0.0; values];
    let Ok(traj) = TrajBatch::new(&data, batch, horizon) else {
        return reached;
    };
    let evaluated = l.constraint.evaluate(traj, &ctx, &mut cost, &mut grad);
    if let Err(e) = &evaluated {
        let message = e.to_string();
        assert!(
            !message.contains("panicked:"),
            "the personal_space plugin panicked: {message}"
        );
    }
    if evaluated.is_ok() {
        let finite_in = data.iter().all(|v| v.is_finite())
            && ctx.dt.is_finite()
            && obs.agents.iter().all(|a| {
                a.position.iter().chain(&a.velocity).all(|v| v.is_finite()) && a.radius.is_finite()
            });
        assert!(
            wrong == 0 && (!finite_in || cost.iter().chain(&grad).all(|v| !v.is_nan())),
            "the constraint returned NaN for finite inputs (or accepted wrong output sizes)"
        );
        reached.evaluated = true;
    }
    reached
}

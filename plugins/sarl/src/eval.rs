//! Running whole circle-crossing episodes with a policy, and outcome statistics.
//!
//! Episodes are identified by a [`SeedStream`] and an index, so every episode can be replayed
//! on its own (training, validation and the held-out test use disjoint streams).

use crate::action::ActionSpace;
use crate::env::{CircleCrossing, EnvConfig, Outcome};
use crate::error::SarlError;
use crate::net::SarlNet;
use crate::policy::{LookAhead, select_action};
use crate::state::{JOINT_DIM, RobotState, push_joint_states};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Disjoint streams of episodes drawn from one master seed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeedStream {
    /// Imitation-learning demonstrations.
    Demo,
    /// Reinforcement-learning episodes.
    Train,
    /// Periodic validation during training.
    Validation,
    /// The held-out test episodes reported in the model card.
    Test,
}

impl SeedStream {
    fn tag(self) -> u64 {
        match self {
            Self::Demo => 1,
            Self::Train => 2,
            Self::Validation => 3,
            Self::Test => 4,
        }
    }
}

/// SplitMix64 finaliser (mixes the seed, stream and index into one RNG seed).
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// The RNG of episode `index` of `stream` under master seed `seed`.
pub fn episode_rng(seed: u64, stream: SeedStream, index: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(mix(mix(seed ^ stream.tag().rotate_left(56)) ^ index))
}

/// Who controls the robot.
#[derive(Clone, Copy, Debug)]
pub enum Policy<'a> {
    /// SARL's look-ahead, ε-greedy (ε = 0 for evaluation).
    Sarl {
        net: &'a SarlNet,
        actions: &'a ActionSpace,
        lookahead: LookAhead,
        epsilon: f64,
    },
    /// Straight at the goal at `v_pref` (slowing down within one step of it).
    Straight,
    /// ORCA among the humans with `safety_space` added to the robot's radius (the imitation
    /// demonstrator).
    Orca { safety_space: f64 },
}

/// One finished episode.
#[derive(Clone, Debug, PartialEq)]
pub struct Episode {
    pub outcome: Outcome,
    /// Episode length (s).
    pub time: f64,
    /// Joint states the robot acted from, `steps × humans × 13` numbers.
    pub states: Vec<f32>,
    /// Reward of each step.
    pub rewards: Vec<f64>,
    /// Humans per state.
    pub humans: usize,
}

impl Episode {
    /// Number of steps.
    pub fn steps(&self) -> usize {
        self.rewards.len()
    }
}

/// Runs one episode of `cfg` drawn with `rng` (which also drives ε-greedy exploration).
pub fn run_episode(
    cfg: &EnvConfig,
    policy: &Policy<'_>,
    rng: &mut ChaCha8Rng,
) -> Result<Episode, SarlError> {
    let mut env = CircleCrossing::new(cfg, rng);
    let humans = env.humans().len();
    let mut states = Vec::new();
    let mut rewards = Vec::new();
    loop {
        let robot: RobotState = *env.robot();
        let start = states.len();
        push_joint_states(&robot, env.humans(), true, &mut states);
        debug_assert_eq!(states.len() - start, humans * JOINT_DIM);
        let action = match policy {
            Policy::Sarl {
                net,
                actions,
                lookahead,
                epsilon,
            } => {
                if *epsilon > 0.0 && rng.random::<f64>() < *epsilon {
                    actions.actions[rng.random_range(0..actions.len())]
                } else {
                    select_action(net, actions, &robot, env.humans(), lookahead)?.velocity
                }
            }
            Policy::Straight => {
                let d = robot.goal_distance();
                let speed = robot.v_pref.min(d / cfg.time_step);
                if d > 0.0 {
                    [
                        (robot.gx - robot.px) / d * speed,
                        (robot.gy - robot.py) / d * speed,
                    ]
                } else {
                    [0.0, 0.0]
                }
            }
            Policy::Orca { safety_space } => env.robot_orca_velocity(*safety_space),
        };
        let step = env.step(action);
        rewards.push(step.reward);
        if let Some(outcome) = step.outcome {
            return Ok(Episode {
                outcome,
                time: env.time(),
                states,
                rewards,
                humans,
            });
        }
    }
}

/// Outcome rates over a set of episodes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct EvalStats {
    pub episodes: usize,
    pub success_rate: f64,
    pub collision_rate: f64,
    pub timeout_rate: f64,
    /// Mean episode time of the successes (s; 0 without any).
    pub mean_success_time: f64,
}

impl EvalStats {
    /// Statistics of finished episodes given as (outcome, time).
    pub fn from_outcomes(outcomes: &[(Outcome, f64)]) -> Self {
        let n = outcomes.len();
        if n == 0 {
            return Self::default();
        }
        let count = |o: Outcome| outcomes.iter().filter(|(x, _)| *x == o).count();
        let s = count(Outcome::Success);
        let success_time: f64 = outcomes
            .iter()
            .filter(|(x, _)| *x == Outcome::Success)
            .map(|(_, t)| t)
            .sum();
        Self {
            episodes: n,
            success_rate: s as f64 / n as f64,
            collision_rate: count(Outcome::Collision) as f64 / n as f64,
            timeout_rate: count(Outcome::Timeout) as f64 / n as f64,
            mean_success_time: if s > 0 { success_time / s as f64 } else { 0.0 },
        }
    }
}

/// Runs episodes `0..n` of `stream` with `policy` and summarises them. `progress` is called
/// after every episode with the number done.
pub fn evaluate(
    cfg: &EnvConfig,
    policy: &Policy<'_>,
    seed: u64,
    stream: SeedStream,
    n: usize,
    progress: &mut dyn FnMut(usize),
) -> Result<EvalStats, SarlError> {
    let mut outcomes = Vec::with_capacity(n);
    for i in 0..n {
        let mut rng = episode_rng(seed, stream, i as u64);
        let ep = run_episode(cfg, policy, &mut rng)?;
        outcomes.push((ep.outcome, ep.time));
        progress(i + 1);
    }
    Ok(EvalStats::from_outcomes(&outcomes))
}

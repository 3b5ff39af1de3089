//! A seeded social-force crowd (Helbing & Molnár 1995) that produces scenes, training tuples
//! and episodes of the four flow classes in exactly the formats of the real data, so a
//! machine without the datasets can run the demo and the tests.
//!
//! # Model
//! Each pedestrian `i` has a desired speed `v0_i` (uniform in 0.9–1.5 m/s) towards its goal
//! and feels `f_i = (v0_i·e_i − v_i)/τ + Σ_j A·exp((2r − d_ij)/B)·w(φ_ij)·n_ij` with
//! `τ = 0.5 s`, `A = 2.0 m/s²`, `B = 0.3 m`, `r = 0.3 m`, anisotropy
//! `w(φ) = λ + (1 − λ)(1 + cos φ)/2`, `λ = 0.35`, where `φ_ij` is the angle between `i`'s
//! heading and the direction to `j`. Speeds are capped at `1.3·v0_i`; integration is
//! semi-implicit Euler at 0.05 s, recorded every 0.1 s.
//!
//! # Scenarios
//! The ego walks from the origin along `+x` (its episode goal is 5 m ahead). The other
//! agents (1–15) are placed so that they interact with it: co-flow agents start around the
//! ego's path heading `+x`; counter-flow agents start 5–14 m ahead heading `−x`; cross-flow
//! agents head `±y` and are timed to reach a point of the path when the ego does;
//! multidirection mixes the three. A generated scene is mined with the same
//! [`scenario::try_episode`](crate::scenario::try_episode) rule as real data and redrawn (from
//! the same seeded stream) until its class matches the requested one, so synthetic labels
//! mean what real labels mean.

use crate::resample::{ResampleOptions, ResampleStats, Scene, Track, central_difference, headings};
use crate::scenario::{Episode, MiningOptions, ScenarioClass, try_episode};
use crate::track::AgentClass;
use crate::tuples::{CompactTuple, TrainingTuple, TupleOptions, scene_tuples};
use human2nav_core::bev::BevSpec;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use std::f64::consts::{FRAC_PI_2, PI};

/// Social-force parameters (module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct SocialForce {
    /// Relaxation time `τ` toward the desired velocity, seconds.
    pub tau: f64,
    /// Strength `A` of the repulsion between pedestrians, m/s².
    pub a: f64,
    /// Range `B` of the repulsion, metres.
    pub b: f64,
    /// Anisotropy `λ`: the weight of a pedestrian behind (1: as much as in front).
    pub lambda: f64,
    /// Body radius `r`, metres.
    pub radius: f64,
    /// Recording interval, seconds.
    pub dt: f64,
    /// Integration steps per recording interval.
    pub substeps: usize,
    /// Speeds are capped at this multiple of the desired speed.
    pub max_speed_factor: f64,
}

impl Default for SocialForce {
    fn default() -> Self {
        Self {
            tau: 0.5,
            a: 2.0,
            b: 0.3,
            lambda: 0.35,
            radius: 0.3,
            dt: 0.1,
            substeps: 2,
            max_speed_factor: 1.3,
        }
    }
}

/// A simulated pedestrian.
#[derive(Clone, Debug, PartialEq)]
pub struct Walker {
    /// Position, metres.
    pub p: [f64; 2],
    /// Velocity, m/s.
    pub v: [f64; 2],
    /// Where it walks to, metres.
    pub goal: [f64; 2],
    /// Desired speed, m/s.
    pub v0: f64,
}

impl SocialForce {
    /// Simulates `steps` recording intervals; returns `steps + 1` positions per walker.
    pub fn simulate(&self, walkers: &mut [Walker], steps: usize) -> Vec<Vec<[f64; 2]>> {
        let n = walkers.len();
        let mut out: Vec<Vec<[f64; 2]>> = walkers.iter().map(|w| vec![w.p]).collect();
        let h = self.dt / self.substeps as f64;
        let mut force = vec![[0.0; 2]; n];
        for _ in 0..steps {
            for _ in 0..self.substeps {
                for i in 0..n {
                    let w = &walkers[i];
                    let to_goal = [w.goal[0] - w.p[0], w.goal[1] - w.p[1]];
                    let d = to_goal[0].hypot(to_goal[1]);
                    let desired = if d > 0.2 {
                        [w.v0 * to_goal[0] / d, w.v0 * to_goal[1] / d]
                    } else {
                        [0.0, 0.0]
                    };
                    let mut f = [
                        (desired[0] - w.v[0]) / self.tau,
                        (desired[1] - w.v[1]) / self.tau,
                    ];
                    let speed = w.v[0].hypot(w.v[1]);
                    for j in 0..n {
                        if j == i {
                            continue;
                        }
                        let o = &walkers[j];
                        let dx = [w.p[0] - o.p[0], w.p[1] - o.p[1]];
                        let dij = dx[0].hypot(dx[1]).max(1e-6);
                        if dij > 6.0 {
                            continue;
                        }
                        let nij = [dx[0] / dij, dx[1] / dij];
                        // cos φ between i's heading and the direction towards j (= −n_ij).
                        let cos_phi = if speed > 1e-6 {
                            -(w.v[0] * nij[0] + w.v[1] * nij[1]) / speed
                        } else {
                            1.0
                        };
                        let wgt = self.lambda + (1.0 - self.lambda) * 0.5 * (1.0 + cos_phi);
                        let mag = self.a * ((2.0 * self.radius - dij) / self.b).exp() * wgt;
                        f[0] += mag * nij[0];
                        f[1] += mag * nij[1];
                    }
                    force[i] = f;
                }
                for (w, f) in walkers.iter_mut().zip(&force) {
                    w.v[0] += h * f[0];
                    w.v[1] += h * f[1];
                    let s = w.v[0].hypot(w.v[1]);
                    let cap = self.max_speed_factor * w.v0;
                    if s > cap {
                        w.v = [w.v[0] * cap / s, w.v[1] * cap / s];
                    }
                    w.p[0] += h * w.v[0];
                    w.p[1] += h * w.v[1];
                }
            }
            for (o, w) in out.iter_mut().zip(walkers.iter()) {
                o.push(w.p);
            }
        }
        out
    }
}

fn unit(a: f64) -> [f64; 2] {
    [a.cos(), a.sin()]
}

fn far_enough(p: [f64; 2], placed: &[[f64; 2]], min: f64) -> bool {
    placed
        .iter()
        .all(|q| (p[0] - q[0]).hypot(p[1] - q[1]) >= min)
}

/// Places the ego and `n` others for `class` (module docs). Walker 0 is the ego.
pub fn place(class: ScenarioClass, n: usize, rng: &mut ChaCha8Rng) -> Vec<Walker> {
    let sigma = 10f64.to_radians();
    let jitter = |rng: &mut ChaCha8Rng| -> f64 { sigma * rng.sample::<f64, _>(StandardNormal) };
    let ego_v0 = rng.random_range(1.1..1.4);
    let mut walkers = vec![Walker {
        p: [0.0, 0.0],
        v: [ego_v0, 0.0],
        goal: [40.0, 0.0],
        v0: ego_v0,
    }];
    let mut placed = vec![[0.0, 0.0]];
    let flows: Vec<ScenarioClass> = (0..n)
        .map(|i| match class {
            ScenarioClass::MultidirectionFlow => [
                ScenarioClass::CrossFlow,
                ScenarioClass::CounterFlow,
                ScenarioClass::CoFlow,
            ][i % 3],
            c => c,
        })
        .collect();
    for flow in flows {
        for _ in 0..200 {
            let v0: f64 = rng.random_range(0.9..1.5);
            let (p, dir) = match flow {
                ScenarioClass::CoFlow => {
                    let p = [rng.random_range(-2.0..7.0), rng.random_range(-2.0..2.0)];
                    (p, jitter(rng))
                }
                ScenarioClass::CounterFlow => {
                    let p = [rng.random_range(5.0..14.0), rng.random_range(-2.0..2.0)];
                    (p, PI + jitter(rng))
                }
                _ => {
                    let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
                    let dir = side * FRAC_PI_2 + jitter(rng);
                    let q = [rng.random_range(0.5..5.0), rng.random_range(-0.5..0.5)];
                    let tq = (q[0] / ego_v0 + rng.random_range(-1.5..1.5)).max(0.5);
                    let u = unit(dir);
                    ([q[0] - u[0] * v0 * tq, q[1] - u[1] * v0 * tq], dir)
                }
            };
            if (p[0].hypot(p[1])) < 1.5 || !far_enough(p, &placed, 0.9) {
                continue;
            }
            let u = unit(dir);
            placed.push(p);
            walkers.push(Walker {
                p,
                v: [v0 * u[0], v0 * u[1]],
                goal: [p[0] + 40.0 * u[0], p[1] + 40.0 * u[1]],
                v0,
            });
            break;
        }
    }
    walkers
}

/// Turns simulated positions (0.1 s apart, starting at step 0) into a [`Scene`].
pub fn scene_from_positions(name: &str, positions: Vec<Vec<[f64; 2]>>) -> Scene {
    let opts = ResampleOptions::default();
    let tracks: Vec<Track> = positions
        .into_iter()
        .enumerate()
        .map(|(i, p)| {
            let velocities = central_difference(&p, opts.dt);
            let (headings, _) = headings(&p, opts.dt, &opts);
            Track {
                id: i as u64,
                source_id: i as u64,
                class: AgentClass::Pedestrian,
                start: 0,
                positions: p,
                velocities,
                headings,
            }
        })
        .collect();
    let n = tracks.len();
    Scene {
        name: name.to_string(),
        dataset: "synthetic".into(),
        format: "social_force".into(),
        dt: opts.dt,
        tracks,
        stats: ResampleStats {
            input_tracks: n,
            output_tracks: n,
            ..Default::default()
        },
        dropped: Vec::new(),
    }
}

/// Total simulated time of one synthetic scene, seconds (budget 12.5 s plus margin).
pub const SCENE_DURATION: f64 = 14.0;

fn rng_for(seed: u64, i: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        seed ^ i
            .wrapping_mul(0x9E37_79B9_7F4A_7C15)
            .wrapping_add(0x2545_F491),
    )
}

/// One synthetic scene of `class` and the episode mined from its ego, drawn from `rng` until
/// the mined class matches (at most 200 draws; `None` if none matched).
pub fn scene_and_episode(
    class: ScenarioClass,
    name: &str,
    rng: &mut ChaCha8Rng,
    opts: &MiningOptions,
) -> Option<(Scene, Episode)> {
    let sf = SocialForce::default();
    let steps = (SCENE_DURATION / sf.dt).round() as usize;
    for _ in 0..200 {
        let lo = if class == ScenarioClass::MultidirectionFlow {
            3
        } else {
            1
        };
        let n = rng.random_range(lo..=opts.max_density.max(lo));
        let mut walkers = place(class, n, rng);
        let positions = sf.simulate(&mut walkers, steps);
        let scene = scene_from_positions(name, positions);
        let index = scene.index();
        if let Ok((mut ep, _)) = try_episode(&scene, &index, 0, 0, opts)
            && ep.scenario == class
        {
            ep.id = format!("{name}/{}", class.name());
            return Some((scene, ep));
        }
    }
    None
}

/// `n` synthetic episodes of `class`, deterministic in `seed`.
pub fn episodes(class: ScenarioClass, n: usize, seed: u64) -> Vec<Episode> {
    episodes_with(class, n, seed, &MiningOptions::default())
}

/// [`episodes`] with explicit mining options.
pub fn episodes_with(
    class: ScenarioClass,
    n: usize,
    seed: u64,
    opts: &MiningOptions,
) -> Vec<Episode> {
    (0..n as u64)
        .filter_map(|i| {
            let mut rng = rng_for(seed ^ ((class.index() as u64) << 40), i);
            let name = format!("synthetic/{}_{i:04}", class.name());
            scene_and_episode(class, &name, &mut rng, opts).map(|(_, e)| e)
        })
        .collect()
}

/// `n` synthetic scenes cycling through the four classes, deterministic in `seed`.
pub fn scenes(n: usize, seed: u64) -> Vec<Scene> {
    scenes_range(0, n, seed)
}

/// Scenes `first .. first + n` of the sequence [`scenes`] draws (for parallel generation).
pub fn scenes_range(first: usize, n: usize, seed: u64) -> Vec<Scene> {
    let opts = MiningOptions::default();
    (first as u64..(first + n) as u64)
        .filter_map(|i| {
            let class = ScenarioClass::ALL[(i % 4) as usize];
            let mut rng = rng_for(seed, i);
            scene_and_episode(class, &format!("synthetic/scene_{i:04}"), &mut rng, &opts)
                .map(|(s, _)| s)
        })
        .collect()
}

/// `n` compact tuples from synthetic scenes (every walker serves as an ego), deterministic in
/// `seed`.
pub fn compact_tuples(
    n: usize,
    seed: u64,
    spec: &BevSpec,
    opts: &TupleOptions,
) -> Vec<CompactTuple> {
    let mut out = Vec::with_capacity(n);
    let mut i = 0u64;
    while out.len() < n && i < 100_000 {
        let class = ScenarioClass::ALL[(i % 4) as usize];
        let mut rng = rng_for(seed, i);
        if let Some((scene, _)) = scene_and_episode(
            class,
            "synthetic/tuples",
            &mut rng,
            &MiningOptions::default(),
        ) {
            let (t, _) = scene_tuples(&scene, (i % u16::MAX as u64) as u16, spec, opts);
            out.extend(t.into_iter().take(n - out.len()));
        }
        i += 1;
    }
    out
}

/// `n` dense training tuples with the default BEV spec and tuple options (for tests of the
/// flow model that must run without datasets). Deterministic in `seed`.
pub fn tuples(n: usize, seed: u64) -> Vec<TrainingTuple> {
    let spec = BevSpec::default();
    compact_tuples(n, seed, &spec, &TupleOptions::default())
        .iter()
        .map(|t| t.to_tuple(&spec))
        .collect()
}

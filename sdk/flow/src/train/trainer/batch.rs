//! Training batches: the random draws of a batch ([`BatchDraws`]) and the batch they make in
//! tensor form ([`Batch`]): the path point of Eq. 3, its target and the network's inputs.

use crate::cfm::{TimeSampler, geodesic_point, target_velocity};
use crate::config::{NetConfig, Normalisation};
use crate::model::{crowd_points, normalise_condition, trajectory_features};
use crate::net::CROWD_FEATURES;
use crate::train::{ClearanceLoss, Counterfactual, TrainingSample, scaled, unit_normal_twist};
use human2nav_core::bev::{BevSpec, overlay_agent};
use human2nav_core::se2::{Pose2, Twist2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tch::{Device, Tensor};

/// Draws `[K, 4]` uniforms for the counterfactual walkers from a generator of their own, so
/// that the other draws of a batch are the same with or without them.
pub(super) struct CounterfactualNoise<'a> {
    opts: &'a Counterfactual,
    rng: ChaCha8Rng,
}

impl<'a> CounterfactualNoise<'a> {
    pub(super) fn new(opts: Option<&'a Counterfactual>, seed: u64, stream: u64) -> Option<Self> {
        opts.map(|opts| {
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x5eed_c0f7_ac7a_0001);
            rng.set_stream(stream);
            Self { opts, rng }
        })
    }
}

/// A training batch in tensor form: the network's inputs and the regression target of Eq. 3.
#[derive(Debug)]
pub struct Batch {
    /// `[B, 5, T]` features of the path point `x_t` ([`trajectory_features`]).
    pub x: Tensor,
    /// `[B]` flow times.
    pub t: Tensor,
    /// `[B, 3, H, W]` normalised BEV rasters.
    pub bev: Tensor,
    /// `[B, 4]` normalised goal and ego velocity.
    pub goal_vel: Tensor,
    /// `[B, N, 5]` crowd points of the (mirrored) rasters (`N = 0` without the crowd pathway).
    pub points: Tensor,
    /// `[B, 3, T]` standardised target velocities `ξ/σ`.
    pub target: Tensor,
    /// `[B, 3, T]` the path point `x_t` itself: normalised translations and heading.
    pub xt: Tensor,
    /// `[B, P, 5]` the people the clearance term keeps the endpoint from, read from the
    /// (mirrored, augmented) rasters as [`crowd_points`] reads them (`P = 0` without the term).
    pub people: Tensor,
}

/// Eq. 3's path noise: `σ` and its own generator, so that the source draws, flow times and
/// targets of a batch are the same with or without it.
pub(super) struct PathNoise {
    sigma: f64,
    rng: ChaCha8Rng,
}

impl PathNoise {
    /// The noise of batch `stream` of a run seeded `seed` (`None` when `sigma` is 0).
    pub(super) fn new(sigma: f64, seed: u64, stream: u64) -> Option<Self> {
        (sigma > 0.0).then(|| {
            // A seed of its own: the batch generator is seeded with `seed` itself.
            let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
            rng.set_stream(stream);
            Self { sigma, rng }
        })
    }
}

/// The random part of a batch (per-waypoint entries row-major; `x_0 = exp(ξ_0)`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BatchDraws {
    /// Per row: mirrored (y ↦ −y) or not.
    pub flip: Vec<bool>,
    /// Per row: the flow time.
    pub t: Vec<f64>,
    /// Per row and waypoint: the source twist `ξ_0`.
    pub source: Vec<Twist2>,
    /// Per row and waypoint: the path noise twist, scaled by `σ`; empty without path noise.
    pub path: Vec<Twist2>,
    /// Per row: the four uniforms of [`Counterfactual::person`]; empty without
    /// counterfactual walkers.
    pub counterfactual: Vec<[f64; 4]>,
}

/// The draws of a batch of `rows` rows from `rng` (and the path noise's own generator), in
/// the order the trainer has always taken them: per row the mirror flag (only when `mirror`),
/// the flow time, then the waypoints' source twists.
fn draw_batch<R: Rng + ?Sized>(
    rows: usize,
    t_len: usize,
    time: &TimeSampler,
    mirror: bool,
    path: Option<&mut PathNoise>,
    counterfactual: Option<&mut CounterfactualNoise<'_>>,
    rng: &mut R,
) -> BatchDraws {
    let mut path = path.filter(|p| p.sigma > 0.0);
    let mut d = BatchDraws::default();
    for _ in 0..rows {
        d.flip.push(mirror && rng.random_bool(0.5));
        d.t.push(time.sample(rng));
        for _ in 0..t_len {
            d.source.push(unit_normal_twist(rng));
            if let Some(p) = path.as_deref_mut() {
                d.path.push(unit_normal_twist(&mut p.rng).scale(p.sigma));
            }
        }
    }
    if let Some(c) = counterfactual {
        d.counterfactual = (0..rows)
            .map(|_| std::array::from_fn(|_| c.rng.random::<f64>()))
            .collect();
    }
    d
}

/// Builds the batch of examples `idx` with noise from `rng`: features of `x_t`, flow times,
/// normalised conditions and standardised targets `ξ/σ`.
pub(super) fn build_batch<S: TrainingSample, R: Rng + ?Sized>(
    data: &[S],
    idx: &[usize],
    net: &NetConfig,
    norm: &Normalisation,
    time: &TimeSampler,
    mirror: bool,
    path: Option<&mut PathNoise>,
    counterfactual: Option<&mut CounterfactualNoise<'_>>,
    clearance: Option<&ClearanceLoss>,
    rng: &mut R,
    device: Device,
) -> Batch {
    let opts = counterfactual.as_ref().map(|c| c.opts);
    let draws = draw_batch(
        idx.len(),
        net.horizon,
        time,
        mirror,
        path,
        counterfactual,
        rng,
    );
    batch_from_draws(data, idx, net, norm, &draws, opts, clearance, device)
}

/// The batch of examples `idx` given its random part: the recipe of the trainer's batches
/// (the SE(2) geodesic point and target of Eq. 3, trajectory features, mirrored and
/// normalised conditions, counterfactual walkers when `counterfactual` is given, the people of
/// the clearance term when `clearance` is given), public so that a reference implementation can
/// be checked against it on the same draws.
#[allow(clippy::too_many_arguments)]
pub fn batch_from_draws<S: TrainingSample>(
    data: &[S],
    idx: &[usize],
    net: &NetConfig,
    norm: &Normalisation,
    draws: &BatchDraws,
    counterfactual: Option<&Counterfactual>,
    clearance: Option<&ClearanceLoss>,
    device: Device,
) -> Batch {
    let b = idx.len();
    let t_len = net.horizon;
    let bev_len = net.bev_len();
    let cells = net.bev_cells;
    let mut x = vec![0f32; b * 5 * t_len];
    let mut target = vec![0f32; b * 3 * t_len];
    let mut ts = vec![0f32; b];
    let mut bev = vec![0f32; b * bev_len];
    let mut gv = vec![0f32; b * 4];
    let crowd_len = net.crowd_len();
    let mut points = vec![0f32; b * crowd_len];
    let people_cfg = clearance.map(ClearanceLoss::crowd);
    let people_len = people_cfg
        .as_ref()
        .map_or(0, |c| c.points * CROWD_FEATURES as usize);
    let mut people = vec![0f32; b * people_len];
    let mut xt_all = vec![0f32; b * 3 * t_len];
    let mut poses = vec![0f64; t_len * 3];
    let mut flipped = vec![0f32; bev_len];
    let (mut stamped, mut disc) = (vec![0f32; bev_len], vec![0f32; bev_len]);
    let s = norm.position_scale;
    for (row, &i) in idx.iter().enumerate() {
        let ex = &data[i];
        let flip = draws.flip[row];
        let t = draws.t[row];
        ts[row] = t as f32;
        let tgt = &mut target[row * 3 * t_len..(row + 1) * 3 * t_len];
        for j in 0..t_len {
            let mut p1 = scaled(ex.future_pose(j), s);
            if flip {
                p1 = Pose2::new(p1.x, -p1.y, -p1.theta);
            }
            let k = row * t_len + j;
            let x0 = Pose2::exp(draws.source[k]);
            let xi = target_velocity(x0, p1);
            let mut xt = geodesic_point(x0, xi, t);
            if let Some(&noise) = draws.path.get(k) {
                xt = xt.compose(Pose2::exp(noise));
            }
            poses[3 * j..3 * j + 3].copy_from_slice(&xt.to_array());
            for (c, v) in xt.to_array().into_iter().enumerate() {
                xt_all[(row * 3 + c) * t_len + j] = v as f32;
            }
            let xi = xi.to_array();
            for c in 0..3 {
                tgt[c * t_len + j] = (xi[c] / norm.velocity_std[c]) as f32;
            }
        }
        trajectory_features(&poses, &mut x[row * 5 * t_len..(row + 1) * 5 * t_len]);
        let (mut goal, mut vel) = (ex.goal(), ex.velocity());
        let src: &[f32] = if flip {
            // Mirror y: columns reverse (column 0 is the far left), v_y flips sign.
            let plane = cells * cells;
            for c in 0..3 {
                let sign = if c == 2 { -1.0 } else { 1.0 };
                for r in 0..cells {
                    for q in 0..cells {
                        flipped[c * plane + r * cells + q] =
                            sign * ex.bev()[c * plane + r * cells + (cells - 1 - q)];
                    }
                }
            }
            goal[1] = -goal[1];
            vel[1] = -vel[1];
            &flipped
        } else {
            ex.bev()
        };
        let person = counterfactual
            .zip(draws.counterfactual.get(row))
            .and_then(|(c, &u)| {
                let future: Vec<Pose2> = (0..t_len)
                    .map(|j| {
                        let p = ex.future_pose(j);
                        if flip {
                            Pose2::new(p.x, -p.y, -p.theta)
                        } else {
                            p
                        }
                    })
                    .collect();
                c.person(&future, vel, u).map(|a| (c.cell, a))
            });
        let src: &[f32] = match person {
            Some((cell, a)) => {
                stamped.copy_from_slice(src);
                let spec = BevSpec {
                    cells,
                    resolution: cell,
                };
                overlay_agent(spec, a, &mut stamped, &mut disc);
                &stamped
            }
            None => src,
        };
        normalise_condition(
            norm,
            src,
            goal,
            vel,
            &mut bev[row * bev_len..(row + 1) * bev_len],
            &mut gv[row * 4..row * 4 + 4],
        );
        if let Some(c) = &net.crowd {
            let out = &mut points[row * crowd_len..(row + 1) * crowd_len];
            crowd_points(c, norm, cells, src, out);
        }
        if let Some(c) = &people_cfg {
            let out = &mut people[row * people_len..(row + 1) * people_len];
            match &net.crowd {
                // The same cells as the network's crowd pathway (as in the shipped recipe):
                // copied rather than read from the raster a second time.
                Some(n) if n.points == c.points && n.cell == c.cell => {
                    out.copy_from_slice(&points[row * crowd_len..(row + 1) * crowd_len]);
                }
                _ => crowd_points(c, norm, cells, src, out),
            }
        }
    }
    let (bi, ti, ci) = (b as i64, t_len as i64, cells as i64);
    Batch {
        x: Tensor::from_slice(&x).view([bi, 5, ti]).to_device(device),
        t: Tensor::from_slice(&ts).to_device(device),
        bev: Tensor::from_slice(&bev)
            .view([bi, 3, ci, ci])
            .to_device(device),
        goal_vel: Tensor::from_slice(&gv).view([bi, 4]).to_device(device),
        points: Tensor::from_slice(&points)
            .view([bi, -1, CROWD_FEATURES])
            .to_device(device),
        target: Tensor::from_slice(&target)
            .view([bi, 3, ti])
            .to_device(device),
        xt: Tensor::from_slice(&xt_all)
            .view([bi, 3, ti])
            .to_device(device),
        people: Tensor::from_slice(&people)
            .view([bi, -1, CROWD_FEATURES])
            .to_device(device),
    }
}

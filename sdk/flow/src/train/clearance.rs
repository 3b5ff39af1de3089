//! The clearance term of the training loss ([`ClearanceLoss`]) on libtorch tensors.

use super::ClearanceLoss;
use super::trainer::Batch;
use crate::config::Normalisation;
use std::f64::consts::PI;
use tch::{Kind, Tensor};

/// The clearance term of a batch given the network's standardised velocities `pred`
/// (`[B, 3, T]`): the endpoint each row's velocity points to, `x̂_1 = x_t·exp((1 − t)·v)`, in
/// metres, against the batch's people walking on at constant velocity, as
/// [`ClearanceLoss`] defines it. Differentiable in `pred`; 0 for rows without people.
pub fn clearance_penalty(
    pred: &Tensor,
    batch: &Batch,
    norm: &Normalisation,
    c: &ClearanceLoss,
) -> Tensor {
    let device = pred.device();
    let s = norm.position_scale;
    let std = Tensor::from_slice(&norm.velocity_std.map(|v| v as f32))
        .view([1, 3, 1])
        .to_device(device);
    let rest = (batch.t.ones_like() - &batch.t).view([-1, 1]);
    let xi = pred * std;
    let (u, v, w) = (
        xi.select(1, 0) * &rest,
        xi.select(1, 1) * &rest,
        xi.select(1, 2) * &rest,
    );
    // exp of the twist (u, v, w): translation V(w)·(u, v) with V = [[a, −b], [b, a]],
    // a = sin w / w, b = (1 − cos w)/w = sin(w/2)·sinc(w/2); tch's sinc is sin(πx)/(πx).
    let half = &w * 0.5;
    let a = (&w / PI).sinc();
    let b = half.sin() * (&half / PI).sinc();
    let dx = &a * &u - &b * &v;
    let dy = &b * &u + &a * &v;
    let (x, y, th) = (
        batch.xt.select(1, 0),
        batch.xt.select(1, 1),
        batch.xt.select(1, 2),
    );
    let (cos, sin) = (th.cos(), th.sin());
    // [B, 1, T] endpoint waypoints in metres.
    let x1 = ((x + &cos * &dx - &sin * &dy) * s).unsqueeze(1);
    let y1 = ((y + &sin * &dx + &cos * &dy) * s).unsqueeze(1);
    let t_len = pred.size()[2];
    let tau = (Tensor::arange(t_len, (Kind::Float, device)) + 1.0).view([1, 1, -1]) * c.step;
    // [B, P, 1] people: cell centres and velocities in metres, and their mask.
    let person = |k: i64| batch.people.select(2, k).unsqueeze(2);
    let qx = person(0) * s + person(2) * s * &tau;
    let qy = person(1) * s + person(3) * s * &tau;
    let d = ((x1 - qx).square() + (y1 - qy).square() + 1e-12).sqrt();
    let pen = ((d * -1.0 + c.distance) / c.distance).relu().square() * person(4);
    // [B] per row: summed over people, averaged over waypoints, weighted by t^p.
    let per_row = pen
        .sum_dim_intlist(1, false, Kind::Float)
        .mean_dim(1, false, Kind::Float)
        * batch.t.pow_tensor_scalar(c.time_power);
    per_row.mean(Kind::Float) * c.weight
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::NetConfig;
    use crate::train::{BatchDraws, Example, batch_from_draws};
    use human2nav_core::bev::BevSpec;
    use human2nav_core::se2::{Pose2, Twist2};
    use tch::Device;

    const CELLS: usize = 8;

    /// A walker going straight at 1 m/s past one occupied cell that moves towards its path.
    fn scene() -> (Example, NetConfig, Normalisation, ClearanceLoss, [f64; 4]) {
        let net = NetConfig {
            horizon: 8,
            bev_cells: CELLS,
            ..NetConfig::default()
        };
        let future = (1..=8)
            .map(|i| Pose2::new(0.1 * i as f64, 0.02 * i as f64, 0.05 * i as f64))
            .collect();
        let spec = BevSpec {
            cells: CELLS,
            resolution: 0.3,
        };
        let (row, col) = (CELLS / 2 - 2, CELLS / 2 - 1);
        let centre = spec.cell_center(row, col);
        let plane = CELLS * CELLS;
        let mut bev = vec![0f32; 3 * plane];
        let i = row * CELLS + col;
        let vel = [-0.4, -0.3];
        bev[i] = 1.0;
        bev[plane + i] = vel[0] as f32;
        bev[2 * plane + i] = vel[1] as f32;
        let ex = Example {
            bev,
            goal: [3.0, 0.0],
            velocity: [1.0, 0.0],
            future,
        };
        let norm = Normalisation {
            position_scale: 1.7,
            velocity_std: [0.6, 0.3, 0.4],
            ..Normalisation::default()
        };
        let c = ClearanceLoss {
            weight: 2.0,
            distance: 0.9,
            ..ClearanceLoss::default()
        };
        (ex, net, norm, c, [centre[0], centre[1], vel[0], vel[1]])
    }

    fn batch(ex: &Example, net: &NetConfig, norm: &Normalisation, c: &ClearanceLoss) -> Batch {
        let draws = BatchDraws {
            flip: vec![false],
            t: vec![0.35],
            source: (0..8)
                .map(|j| Twist2::new(0.3 - 0.1 * j as f64, 0.2, 0.1 * j as f64 - 0.4))
                .collect(),
            ..BatchDraws::default()
        };
        let data = [ex.clone()];
        batch_from_draws(&data, &[0], net, norm, &draws, None, Some(c), Device::Cpu)
    }

    #[test]
    fn the_target_velocity_lands_on_the_recorded_future() {
        let (ex, net, norm, c, [px, py, vx, vy]) = scene();
        let b = batch(&ex, &net, &norm, &c);
        // With the target as the prediction, x̂_1 is the recorded future: the term is the
        // penalty of the future against the person's constant-velocity walk, by hand.
        let got = clearance_penalty(&b.target, &b, &norm, &c).double_value(&[]);
        let want = c.weight / 8.0
            * ex.future
                .iter()
                .enumerate()
                .map(|(j, p)| {
                    let tau = (j + 1) as f64 * c.step;
                    let d = (p.x - px - vx * tau).hypot(p.y - py - vy * tau);
                    ((c.distance - d) / c.distance).max(0.0).powi(2)
                })
                .sum::<f64>();
        assert!(want > 0.05, "the scene must have a contact: {want}");
        approx::assert_relative_eq!(got, want, max_relative = 1e-4);
        // Weighted by the flow time (0.35) squared.
        let late = ClearanceLoss {
            time_power: 2.0,
            ..c
        };
        let got = clearance_penalty(&b.target, &b, &norm, &late).double_value(&[]);
        approx::assert_relative_eq!(got, want * 0.35 * 0.35, max_relative = 1e-4);
    }

    #[test]
    fn the_term_pushes_the_endpoint_away_and_is_zero_without_people() {
        let (ex, net, norm, c, _) = scene();
        let b = batch(&ex, &net, &norm, &c);
        let pred = b.target.copy().set_requires_grad(true);
        let pen = clearance_penalty(&pred, &b, &norm, &c);
        pen.backward();
        let g = pred.grad();
        assert!(g.isfinite().all().int64_value(&[]) == 1);
        assert!(g.abs().sum(Kind::Float).double_value(&[]) > 0.0);
        // A small step down the gradient lowers the term.
        let stepped = &b.target - g * 0.01;
        let lower = clearance_penalty(&stepped, &b, &norm, &c).double_value(&[]);
        assert!(lower < pen.double_value(&[]));

        let empty = Example {
            bev: vec![0.0; ex.bev.len()],
            ..ex
        };
        let b = batch(&empty, &net, &norm, &c);
        assert_eq!(b.people.size(), [1, c.points as i64, 5]);
        let none = clearance_penalty(&b.target, &b, &norm, &c).double_value(&[]);
        assert_eq!(none, 0.0);
    }

    #[test]
    fn out_of_range_options_are_refused_naming_the_field() {
        for (bad, field) in [
            (
                ClearanceLoss {
                    weight: f64::NAN,
                    ..ClearanceLoss::default()
                },
                "train.clearance.weight",
            ),
            (
                ClearanceLoss {
                    distance: 0.0,
                    ..ClearanceLoss::default()
                },
                "train.clearance.distance",
            ),
            (
                ClearanceLoss {
                    points: 0,
                    ..ClearanceLoss::default()
                },
                "train.clearance.points",
            ),
            (
                ClearanceLoss {
                    time_power: -1.0,
                    ..ClearanceLoss::default()
                },
                "train.clearance.time_power",
            ),
        ] {
            let opts = crate::train::TrainOptions {
                clearance: Some(bad),
                ..Default::default()
            };
            let err = opts.validate().expect_err(field).to_string();
            assert!(err.contains(field), "{err}");
        }
    }
}

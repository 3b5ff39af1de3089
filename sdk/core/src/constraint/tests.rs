use super::*;
use crate::guidance::analytic::demo_batch;
use crate::limits::{CoupledLimit, GuidanceWeights};
use crate::se2::Pose2;
use approx::assert_relative_eq;

fn limits(kappa: Option<f64>) -> Limits {
    Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.5,
        omega_max: 1.0,
        kappa_max: kappa,
        lateral_speed_max: 0.1,
        coupled: None,
    }
}

fn weights() -> GuidanceWeights {
    GuidanceWeights {
        lambda_v: 1.0,
        lambda_a: 0.5,
        lambda_omega: 2.0,
        lambda_kappa: 0.7,
        lambda_lateral: 1.5,
        lambda_reverse: 3.0,
        lambda_coupled: 0.8,
        gamma: 10.0,
        delta: 0.05,
    }
}

const MARGIN: SoftMargin = SoftMargin {
    gamma: 10.0,
    delta: 0.05,
};

fn ctx(l: &Limits) -> ConstraintContext<'_> {
    ConstraintContext {
        dt: 0.1,
        limits: l,
        initial_velocity: Twist2::new(0.7, 0.0, 0.1),
        agents: &[],
        scene: Default::default(),
    }
}

/// Cost per trajectory of `term` and its gradient.
fn eval(
    term: &dyn ConstraintTerm,
    data: &[f64],
    b: usize,
    t: usize,
    c: &ConstraintContext<'_>,
) -> (Vec<f64>, Vec<f64>) {
    let batch = TrajBatch::new(data, b, t).unwrap();
    let mut cost = vec![0.0; b];
    let mut grad = vec![0.0; data.len()];
    term.evaluate(batch, c, &mut cost, &mut grad).unwrap();
    (cost, grad)
}

/// Central finite differences of the summed cost over every coordinate, compared with `grad`.
fn check_gradient(cost_of: impl Fn(&[f64]) -> f64, data: &[f64], grad: &[f64], what: &str) {
    let h = 1e-6;
    let mut p = data.to_vec();
    let mut worst = 0.0f64;
    for j in 0..data.len() {
        p[j] = data[j] + h;
        let up = cost_of(&p);
        p[j] = data[j] - h;
        let down = cost_of(&p);
        p[j] = data[j];
        let fd = (up - down) / (2.0 * h);
        let err = (fd - grad[j]).abs() / (1.0 + fd.abs());
        worst = worst.max(err);
        assert!(
            err < 1e-5,
            "{what}: coordinate {j}: analytic {} vs finite difference {fd}",
            grad[j]
        );
    }
    assert!(worst.is_finite());
}

#[test]
fn softplus_and_sigmoid_closed_forms() {
    assert_relative_eq!(softplus(0.0), std::f64::consts::LN_2, epsilon = 1e-15);
    assert_relative_eq!(softplus(40.0), 40.0, epsilon = 1e-12);
    assert_relative_eq!(softplus(-40.0), (-40.0f64).exp(), max_relative = 1e-9);
    assert_relative_eq!(softplus(1.3), (1.0 + 1.3f64.exp()).ln(), epsilon = 1e-14);
    assert_relative_eq!(sigmoid(0.0), 0.5);
    assert_relative_eq!(sigmoid(-800.0), 0.0);
    assert_relative_eq!(sigmoid(800.0), 1.0);
    // Soft margin at the limit: softplus(γδ)/γ; far beyond: ≈ r − 1 + δ.
    let (p, dp) = MARGIN.abs(1.0);
    assert_relative_eq!(
        p,
        softplus(10.0 * (0.05 - SMOOTH_ABS_EPS + (1.0 + 1e-6f64).sqrt() - 1.0)) / 10.0,
        epsilon = 1e-12
    );
    assert!(dp > 0.5 && dp < 1.0);
    let (p, dp) = MARGIN.abs(-3.0);
    assert_relative_eq!(p, 3.0 - 1.0 + 0.05, epsilon = 2e-3);
    assert_relative_eq!(dp, -1.0, epsilon = 1e-6);
    // |0|_ε is exactly 0.
    let (p0, dp0) = MARGIN.abs(0.0);
    assert_relative_eq!(p0, softplus(-9.5) / 10.0, epsilon = 1e-15);
    assert_relative_eq!(dp0, 0.0);
}

#[test]
fn speed_term_closed_form_on_a_straight_line() {
    // Straight line at 2 m/s from rest-pose: every segment has v = 2, so the cost is the
    // margin of r = 2 exactly (the forward term needs no smoothing).
    let l = limits(None);
    let t = 8;
    let data: Vec<f64> = (0..t).flat_map(|k| [0.2 * k as f64, 0.0, 0.0]).collect();
    let speed = BuiltinTerm::new(BuiltinKind::Speed, MARGIN);
    let (cost, grad) = eval(&speed, &data, 1, t, &ctx(&l));
    assert_relative_eq!(
        cost[0],
        softplus(10.0 * (2.0 - 1.0 + 0.05)) / 10.0,
        epsilon = 1e-12
    );
    // Interior gradients cancel; the last pose is pulled back, the first pushed forward.
    let g = sigmoid(10.5) / (1.0 * 0.1 * (t - 1) as f64);
    assert_relative_eq!(grad[0], -g, epsilon = 1e-12);
    assert_relative_eq!(grad[3 * (t - 1)], g, epsilon = 1e-12);
    for k in 1..t - 1 {
        assert_relative_eq!(grad[3 * k], 0.0, epsilon = 1e-12);
    }
    // The reverse, lateral, yaw-rate and curvature terms see nothing of it.
    for kind in [
        BuiltinKind::Reverse,
        BuiltinKind::Lateral,
        BuiltinKind::YawRate,
    ] {
        let (c, _) = eval(&BuiltinTerm::new(kind, MARGIN), &data, 1, t, &ctx(&l));
        assert!(c[0] < 1e-4, "{kind:?}: {}", c[0]);
    }
}

#[test]
fn acceleration_term_includes_the_initial_acceleration() {
    let l = limits(None);
    let t = 5;
    // Constant 0.7 m/s, equal to the initial speed: nothing to penalise.
    let data: Vec<f64> = (0..t).flat_map(|k| [0.07 * k as f64, 0.0, 0.0]).collect();
    let acc = BuiltinTerm::new(BuiltinKind::Acceleration, MARGIN);
    let (cost, _) = eval(&acc, &data, 1, t, &ctx(&l));
    assert_relative_eq!(cost[0], softplus(-9.5) / 10.0, epsilon = 1e-12);
    // Starting at 0.7 m/s, a plan at 1.0 m/s starts with a 3 m/s² acceleration: one sample of 4
    // at r = 2, the other three at 0.
    let data: Vec<f64> = (0..t).flat_map(|k| [0.1 * k as f64, 0.0, 0.0]).collect();
    let (cost, _) = eval(&acc, &data, 1, t, &ctx(&l));
    let r = (4.0 + SMOOTH_ABS_EPS * SMOOTH_ABS_EPS).sqrt() - SMOOTH_ABS_EPS;
    let expected = (softplus(10.0 * (r - 0.95)) + 3.0 * softplus(-9.5)) / 40.0;
    assert_relative_eq!(cost[0], expected, epsilon = 1e-9);
}

#[test]
fn curvature_term_is_silent_without_a_limit() {
    let l = limits(None);
    let data = demo_batch(3, 10, 0.1);
    let (cost, grad) = eval(
        &BuiltinTerm::new(BuiltinKind::Curvature, MARGIN),
        &data,
        3,
        10,
        &ctx(&l),
    );
    assert!(cost.iter().chain(&grad).all(|&v| v == 0.0));
    let phi = Phi::from_weights(&weights(), &l);
    assert!(phi.terms().all(|(_, n)| n != "curvature"));
    assert_eq!(phi.len(), 5);
    assert_eq!(Phi::from_weights(&weights(), &limits(Some(1.0))).len(), 6);
    assert_eq!(
        Phi::from_weights(&weights(), &with_tracks(limits(Some(1.0)))).len(),
        7
    );
}

/// A tracked base's limit: `|v| + 0.345·|ω| ≤ 1.4` (χ·B/2 = 0.345 m), with a lateral part so
/// that every coefficient is exercised.
const TRACKS: CoupledLimit = CoupledLimit {
    v: 1.0,
    lateral: 0.5,
    omega: 0.345,
    max: 1.4,
};

fn with_tracks(mut l: Limits) -> Limits {
    l.coupled = Some(TRACKS);
    l
}

#[test]
fn coupled_term_closed_form_on_an_arc_and_silent_without_a_limit() {
    // An arc at v = 1.2 m/s, ω = 1.2 rad/s: 1.2 + 0.345·1.2 = 1.614 > 1.4, the faster track
    // over its limit, though v and ω are each within theirs (v_max 1.2 on a tracked base).
    let t = 8;
    let dt = 0.1;
    let mut pose = Pose2::IDENTITY;
    let mut data = Vec::new();
    for _ in 0..t {
        data.extend(pose.to_array());
        pose = pose.euler_step(Twist2::new(1.2, 0.0, 1.2), dt);
    }
    let term = BuiltinTerm::new(BuiltinKind::Coupled, MARGIN);
    let l = with_tracks(limits(None));
    let (cost, _) = eval(&term, &data, 1, t, &ctx(&l));
    // Segment speeds are chords (c = sinc(0.06) ≈ 0.9994 of 1.2); every segment is the same.
    let (v, vy, w) = crate::trajectory::segment_values(&data[0..3], &data[3..6], dt);
    let eps = SMOOTH_ABS_EPS * TRACKS.max;
    let sabs = |x: f64| (x * x + eps * eps).sqrt() - eps;
    let q = sabs(v) + 0.5 * sabs(vy) + 0.345 * sabs(w);
    assert!(q > 1.6 && q < 1.62, "{q}");
    assert_relative_eq!(
        cost[0],
        softplus(10.0 * (q / 1.4 - 1.0 + 0.05)) / 10.0,
        epsilon = 1e-9
    );
    let (silent, grad) = eval(&term, &data, 1, t, &ctx(&limits(None)));
    assert!(silent[0] == 0.0 && grad.iter().all(|g| *g == 0.0));
    // A bad limit is an error naming the field.
    let mut bad = l;
    bad.coupled = Some(CoupledLimit {
        max: -1.0,
        ..TRACKS
    });
    let mut c = vec![0.0];
    let mut g = vec![0.0; data.len()];
    let err = term
        .evaluate(
            TrajBatch::new(&data, 1, t).unwrap(),
            &ctx(&bad),
            &mut c,
            &mut g,
        )
        .unwrap_err();
    assert!(err.to_string().contains("coupled limit: max"), "{err}");
}

#[test]
fn every_builtin_gradient_matches_finite_differences() {
    let (b, t) = (6, 12);
    let data = demo_batch(b, t, 0.1);
    for l in [limits(Some(0.8)), limits(None), with_tracks(limits(None))] {
        let c = ctx(&l);
        for kind in BuiltinKind::ALL {
            let term = BuiltinTerm::new(kind, MARGIN);
            let (cost, grad) = eval(&term, &data, b, t, &c);
            assert!(cost.iter().all(|v| v.is_finite() && *v >= 0.0));
            let total = |p: &[f64]| eval(&term, p, b, t, &c).0.iter().sum::<f64>();
            check_gradient(total, &data, &grad, kind.name());
        }
    }
}

#[test]
fn gradients_at_rest_and_turning_in_place_are_finite_and_correct() {
    // v = 0 and ω = 0 are where |·| and κ would be non-smooth without the ε's.
    let l = with_tracks(limits(Some(0.5)));
    let c = ConstraintContext {
        initial_velocity: Twist2::ZERO,
        ..ctx(&l)
    };
    let mut data = vec![0.0; 3 * 6];
    for k in 3..6 {
        data[3 * k + 2] = 0.05 * (k - 2) as f64; // turning in place at 0.5 rad/s
    }
    for kind in BuiltinKind::ALL {
        let term = BuiltinTerm::new(kind, MARGIN);
        let (_, grad) = eval(&term, &data, 1, 6, &c);
        let total = |p: &[f64]| eval(&term, p, 1, 6, &c).0[0];
        check_gradient(total, &data, &grad, kind.name());
    }
}

#[test]
fn phi_is_the_weighted_sum_and_its_gradient_matches_finite_differences() {
    let (b, t) = (5, 10);
    let data = demo_batch(b, t, 0.1);
    let l = with_tracks(limits(Some(1.2)));
    let c = ctx(&l);
    let w = weights();
    let phi = Phi::from_weights(&w, &l);
    let mut scratch = PhiScratch::default();
    let batch = TrajBatch::new(&data, b, t).unwrap();
    let mut cost = vec![123.0; b]; // overwritten, not added to
    let mut grad = vec![7.0; data.len()];
    phi.evaluate(batch, &c, &mut cost, &mut grad, &mut scratch)
        .unwrap();

    let mut expected = vec![0.0; b];
    for (weight, kind) in [
        (w.lambda_v, BuiltinKind::Speed),
        (w.lambda_reverse, BuiltinKind::Reverse),
        (w.lambda_a, BuiltinKind::Acceleration),
        (w.lambda_omega, BuiltinKind::YawRate),
        (w.lambda_kappa, BuiltinKind::Curvature),
        (w.lambda_lateral, BuiltinKind::Lateral),
        (w.lambda_coupled, BuiltinKind::Coupled),
    ] {
        let (ct, _) = eval(&BuiltinTerm::new(kind, MARGIN), &data, b, t, &c);
        for k in 0..b {
            expected[k] += weight * ct[k];
        }
    }
    for k in 0..b {
        assert_relative_eq!(cost[k], expected[k], max_relative = 1e-12);
    }
    let total = |p: &[f64]| {
        let mut cs = vec![0.0; b];
        let mut g = vec![0.0; p.len()];
        let mut s = PhiScratch::default();
        phi.evaluate(
            TrajBatch::new(p, b, t).unwrap(),
            &c,
            &mut cs,
            &mut g,
            &mut s,
        )
        .unwrap();
        cs.iter().sum::<f64>()
    };
    check_gradient(total, &data, &grad, "phi");

    // Per-term breakdown is unweighted and sums back to Φ with the weights.
    let mut terms = vec![0.0; phi.len() * b];
    phi.term_costs(batch, &c, &mut terms, &mut scratch).unwrap();
    let weights: Vec<f64> = phi.terms().map(|(w, _)| w).collect();
    for k in 0..b {
        let sum: f64 = (0..phi.len()).map(|j| weights[j] * terms[j * b + k]).sum();
        assert_relative_eq!(sum, cost[k], max_relative = 1e-12);
    }
}

/// A plugin-style term: quadratic pull of every pose's `y` towards 0.
struct CenterLine;

impl ConstraintTerm for CenterLine {
    fn name(&self) -> &str {
        "center_line"
    }

    fn evaluate(
        &self,
        batch: TrajBatch<'_>,
        _ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        for b in 0..batch.batch {
            for (k, p) in batch.trajectory(b).chunks_exact(3).enumerate() {
                cost[b] += p[1] * p[1];
                grad[b * batch.horizon * 3 + 3 * k + 1] += 2.0 * p[1];
            }
        }
        Ok(())
    }
}

#[test]
fn pushed_terms_are_weighted_and_checked() {
    let l = limits(None);
    let c = ctx(&l);
    let mut phi = Phi::new();
    assert!(phi.is_empty());
    phi.push(0.25, Box::new(CenterLine)).unwrap();
    assert!(phi.push(-1.0, Box::new(CenterLine)).is_err());
    assert!(phi.push(f64::NAN, Box::new(CenterLine)).is_err());
    let data = [0.0, 2.0, 0.0, 1.0, -1.0, 0.0];
    let mut cost = [0.0];
    let mut grad = [0.0; 6];
    phi.evaluate(
        TrajBatch::new(&data, 1, 2).unwrap(),
        &c,
        &mut cost,
        &mut grad,
        &mut PhiScratch::default(),
    )
    .unwrap();
    assert_relative_eq!(cost[0], 0.25 * 5.0);
    assert_relative_eq!(grad[1], 1.0);
    assert_relative_eq!(grad[4], -0.5);
    assert_eq!(format!("{phi:?}"), "[(\"center_line\", 0.25)]");
}

#[test]
fn without_limits_keeps_the_pushed_terms_and_drops_the_builtin_ones() {
    let l = limits(Some(1.0));
    let c = ctx(&l);
    let mut phi = Phi::from_weights(&weights(), &l);
    let builtin = phi.len();
    assert!(builtin > 0);
    phi.push(0.25, Box::new(CenterLine)).unwrap();
    let scene = phi.without_limits();
    assert_eq!(scene.len(), 1);
    assert_eq!(
        scene.terms().collect::<Vec<_>>(),
        vec![(0.25, "center_line")]
    );
    assert_eq!(phi.len(), builtin + 1, "the original keeps every term");
    // The scene view scores what the pushed term alone scores.
    let data = demo_batch(2, 4, 0.1);
    let batch = TrajBatch::new(&data, 2, 4).unwrap();
    let (mut all, mut only) = ([0.0; 2], [0.0; 2]);
    let (mut g_all, mut g_only) = (vec![0.0; data.len()], vec![0.0; data.len()]);
    let mut scratch = PhiScratch::default();
    phi.evaluate(batch, &c, &mut all, &mut g_all, &mut scratch)
        .unwrap();
    scene
        .evaluate(batch, &c, &mut only, &mut g_only, &mut scratch)
        .unwrap();
    let mut line = Phi::new();
    line.push(0.25, Box::new(CenterLine)).unwrap();
    let (mut expected, mut g_expected) = ([0.0; 2], vec![0.0; data.len()]);
    line.evaluate(batch, &c, &mut expected, &mut g_expected, &mut scratch)
        .unwrap();
    assert_eq!(only, expected);
    assert_eq!(g_only, g_expected);
    assert!(
        all[0] > only[0] || all[1] > only[1],
        "the limit terms cost something here"
    );
}

#[test]
fn bad_buffers_and_limits_are_errors() {
    let l = limits(None);
    let c = ctx(&l);
    let data = demo_batch(2, 4, 0.1);
    let term = BuiltinTerm::new(BuiltinKind::Speed, MARGIN);
    let batch = TrajBatch::new(&data, 2, 4).unwrap();
    let mut grad = vec![0.0; data.len()];
    assert!(matches!(
        term.evaluate(batch, &c, &mut [0.0; 3], &mut grad),
        Err(ConstraintError::Shape(_))
    ));
    assert!(matches!(
        term.evaluate(batch, &c, &mut [0.0; 2], &mut [0.0; 5]),
        Err(ConstraintError::Shape(_))
    ));
    let bad = Limits { v_max: 0.0, ..l };
    let err = term
        .evaluate(batch, &ctx(&bad), &mut [0.0; 2], &mut grad)
        .unwrap_err();
    assert!(err.to_string().contains("v_max"), "{err}");
    let zero_dt = ConstraintContext { dt: 0.0, ..c };
    assert!(
        term.evaluate(batch, &zero_dt, &mut [0.0; 2], &mut grad)
            .is_err()
    );
    // A single pose has no segment: no cost, no error.
    let one = [0.0, 0.0, 0.0];
    let (cost, _) = eval(&term, &one, 1, 1, &c);
    assert_eq!(cost[0], 0.0);
}

#[test]
fn unicycle_arcs_cost_nothing_laterally() {
    // A differential-drive arc, wrapped around ±π, has vy = 0 on every segment.
    let l = limits(None);
    let mut pose = Pose2::new(0.0, 0.0, 3.0);
    let mut data = Vec::new();
    for _ in 0..20 {
        data.extend_from_slice(&pose.to_array());
        pose = pose.euler_step(Twist2::new(0.8, 0.0, 0.9), 0.1);
    }
    let (cost, _) = eval(
        &BuiltinTerm::new(BuiltinKind::Lateral, MARGIN),
        &data,
        1,
        20,
        &ctx(&l),
    );
    assert_relative_eq!(cost[0], softplus(-9.5) / 10.0, epsilon = 1e-12);
}

/// A term that answers NaN for every trajectory.
struct NotANumber;

impl ConstraintTerm for NotANumber {
    fn name(&self) -> &str {
        "broken_term"
    }

    fn evaluate(
        &self,
        _batch: TrajBatch<'_>,
        _ctx: &ConstraintContext<'_>,
        cost: &mut [f64],
        _grad: &mut [f64],
    ) -> Result<(), ConstraintError> {
        cost.fill(f64::NAN);
        Ok(())
    }
}

#[test]
fn a_term_that_answers_nan_is_an_error_naming_it() {
    let limits = Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    };
    let mut phi = Phi::new();
    phi.push(1.0, Box::new(NotANumber)).unwrap();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::new(0.0, 0.0, 0.0),
        agents: &[],
        scene: Default::default(),
    };
    let data = vec![0.0; 2 * 4 * 3];
    let batch = TrajBatch::new(&data, 2, 4).unwrap();
    let mut scratch = PhiScratch::default();
    let (mut cost, mut grad) = (vec![0.0; 2], vec![0.0; data.len()]);
    let full = phi
        .evaluate(batch, &ctx, &mut cost, &mut grad, &mut scratch)
        .unwrap_err()
        .to_string();
    let fast = phi
        .costs(batch, &ctx, &mut cost, &mut scratch)
        .unwrap_err()
        .to_string();
    for err in [full, fast] {
        assert!(
            err.contains("broken_term") && err.contains("non-finite"),
            "{err}"
        );
    }
}

/// The cost-only path (each term's `cost`, and Φ's `costs`, whose built-in terms share one
/// set of segment values) gives the costs `evaluate` gives, to the bit, on every limit set
/// (curvature and coupled limits present and absent), including trajectories at rest and
/// reversing, and trajectories that share their first poses with the one before (whose
/// shared segments `costs` sums once).
#[test]
fn cost_only_paths_equal_evaluate_bit_for_bit() {
    let (b, t) = (10, 12);
    let mut data = demo_batch(b, t, 0.1);
    // One trajectory at rest, one driven backwards.
    let rest: Vec<f64> = (0..t).flat_map(|_| [0.3, -0.2, 0.5]).collect();
    data[..3 * t].copy_from_slice(&rest);
    for i in 0..t {
        data[3 * t + 3 * i] = -0.05 * i as f64;
    }
    // Trajectory 3 shares 5 poses with 2, 4 is 3 again, 5 shares 1 pose (no segment) with 4,
    // 6 shares all but its last pose with 5.
    let copy = |data: &mut Vec<f64>, from: usize, to: usize, poses: usize| {
        data.copy_within(3 * t * from..3 * t * from + 3 * poses, 3 * t * to);
    };
    copy(&mut data, 2, 3, 5);
    copy(&mut data, 3, 4, t);
    copy(&mut data, 4, 5, 1);
    copy(&mut data, 5, 6, t - 1);
    for l in [
        limits(Some(0.8)),
        limits(None),
        with_tracks(limits(None)),
        with_tracks(limits(Some(1.2))),
    ] {
        let c = ctx(&l);
        let batch = TrajBatch::new(&data, b, t).unwrap();
        for kind in BuiltinKind::ALL {
            let term = BuiltinTerm::new(kind, MARGIN);
            let (expected, _) = eval(&term, &data, b, t, &c);
            let mut cost = vec![0.0; b];
            term.cost(batch, &c, &mut cost).unwrap();
            assert_eq!(cost, expected, "{}", kind.name());
        }
        let phi = Phi::from_weights(&weights(), &l);
        let mut scratch = PhiScratch::default();
        let (mut expected, mut grad) = (vec![0.0; b], vec![0.0; data.len()]);
        phi.evaluate(batch, &c, &mut expected, &mut grad, &mut scratch)
            .unwrap();
        let mut cost = vec![0.0; b];
        phi.costs(batch, &c, &mut cost, &mut scratch).unwrap();
        assert_eq!(cost, expected);
    }
}

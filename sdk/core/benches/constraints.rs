//! Cost of the feasibility penalty and of guidance without a network.
//!
//! * `phi/evaluate_64x32`: Φ (every built-in term, curvature included) with its gradient on 64
//!   trajectories of 33 poses (the current pose and 32 generated ones), as guidance calls it;
//! * `phi/term/<name>`: each built-in term alone on the same batch;
//! * `guidance/geodesic_k16_t32`: Algorithm 1 with the default settings on 16 samples of 32
//!   poses under the analytic geodesic field towards an infeasible target, i.e. everything
//!   guidance costs besides the flow network (which dominates with a real model).
//!
//! Run: `cargo bench -p human2nav-core --bench constraints`.

use criterion::{Criterion, criterion_group, criterion_main};
use human2nav_core::constraint::{
    BuiltinKind, BuiltinTerm, ConstraintContext, ConstraintTerm, Phi, PhiScratch, SoftMargin,
    TrajBatch,
};
use human2nav_core::guidance::analytic::{GeodesicTarget, demo_batch};
use human2nav_core::guidance::{GuidanceSettings, GuidanceWorkspace, sample_guided};
use human2nav_core::{FlowCondition, GuidanceWeights, Limits, Pose2, Twist2};
use std::hint::black_box;

fn limits() -> Limits {
    Limits {
        v_max: 1.0,
        v_reverse_max: 0.3,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: Some(1.0),
        lateral_speed_max: 0.1,
        coupled: None,
    }
}

fn bench_phi(c: &mut Criterion) {
    let (b, t) = (64, 33);
    let data = demo_batch(b, t, 0.1);
    let l = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::new(0.8, 0.0, 0.0),
        agents: &[],
        scene: Default::default(),
    };
    let phi = Phi::from_weights(&GuidanceWeights::default(), &l);
    let batch = TrajBatch::new(&data, b, t).expect("demo batch has the right shape");
    let mut cost = vec![0.0; b];
    let mut grad = vec![0.0; data.len()];
    let mut scratch = PhiScratch::default();
    c.bench_function("phi/evaluate_64x32", |bench| {
        bench.iter(|| {
            phi.evaluate(black_box(batch), &ctx, &mut cost, &mut grad, &mut scratch)
                .expect("phi evaluates");
            black_box(&cost);
        })
    });
    let margin = SoftMargin {
        gamma: 10.0,
        delta: 0.05,
    };
    for kind in BuiltinKind::ALL {
        let term = BuiltinTerm::new(kind, margin);
        c.bench_function(&format!("phi/term/{}", kind.name()), |bench| {
            bench.iter(|| {
                cost.fill(0.0);
                grad.fill(0.0);
                term.evaluate(black_box(batch), &ctx, &mut cost, &mut grad)
                    .expect("term evaluates");
                black_box(&cost);
            })
        });
    }
}

fn bench_guidance(c: &mut Criterion) {
    let (k, t) = (16, 32);
    let mut target = Vec::new();
    let mut pose = Pose2::IDENTITY;
    for _ in 0..t {
        pose = pose.euler_step(Twist2::new(1.3, 0.0, 0.4), 0.1);
        target.extend_from_slice(&pose.to_array());
    }
    let model = GeodesicTarget { target };
    let l = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &l,
        initial_velocity: Twist2::new(1.0, 0.0, 0.0),
        agents: &[],
        scene: Default::default(),
    };
    let phi = Phi::from_weights(&GuidanceWeights::default(), &l);
    let cond = FlowCondition {
        bev: Vec::new(),
        goal: [5.0, 0.0],
        velocity: [1.0, 0.0],
    };
    // Deterministic spread of source poses around the identity.
    let x0: Vec<f64> = (0..k * t)
        .flat_map(|i| {
            let f = i as f64;
            let xi = Twist2::new((0.37 * f).sin(), (0.73 * f).cos(), 0.5 * (1.1 * f).sin());
            Pose2::exp(xi).to_array()
        })
        .collect();
    let settings = GuidanceSettings {
        tolerance: 0.0,
        ..GuidanceSettings::default()
    };
    let mut ws = GuidanceWorkspace::new();
    c.bench_function("guidance/geodesic_k16_t32", |bench| {
        bench.iter(|| {
            let r = sample_guided(
                &model,
                &cond,
                black_box(&x0),
                &phi,
                &ctx,
                &settings,
                &mut ws,
            )
            .expect("guidance runs");
            black_box(r.guided);
        })
    });
}

criterion_group!(benches, bench_phi, bench_guidance);
criterion_main!(benches);

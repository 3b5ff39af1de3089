//! Tests of the evaluation: scene windows, guided windows, displacement errors, the
//! constant-velocity baseline, the proximity rate and the crowd probe.

use super::*;
use approx::assert_relative_eq;
use human2nav_core::guidance::analytic::FixedWalk;

#[test]
fn scene_windows_match_tuples_and_carry_true_neighbour_futures() {
    let scene = human2nav_data::synthetic::scenes(1, 4).remove(0);
    let spec = BevSpec::default();
    let opts = TupleOptions::default();
    let (tuples, _) = scene_tuples(&scene, 0, &spec, &opts);
    let windows = scene_windows(&scene, 0, &spec, &opts).unwrap();
    assert_eq!(windows.len(), tuples.len());
    assert!(!windows.is_empty());
    for (w, t) in windows.iter().zip(&tuples) {
        assert_relative_eq!(w.future[5].x, t.future[5][0] as f64, epsilon = 1e-6);
        assert_relative_eq!(w.cond.goal[1], t.goal[1] as f64, epsilon = 1e-6);
    }
    // A crowd scene: windows see other agents, and an agent observed now at the position the
    // tuple stores is found again at the first future step close to where its velocity
    // takes it.
    let with_others = windows.iter().filter(|w| !w.others.is_empty()).count();
    assert!(with_others > windows.len() / 2);
    let (w, t) = windows
        .iter()
        .zip(&tuples)
        .find(|(_, t)| !t.agents.is_empty())
        .unwrap();
    let a = t.agents[0];
    let expect = [
        a[0] as f64 + 0.1 * a[2] as f64,
        a[1] as f64 + 0.1 * a[3] as f64,
    ];
    let nearest = w
        .others
        .iter()
        .filter_map(|o| o[0])
        .map(|p| (p[0] - expect[0]).hypot(p[1] - expect[1]))
        .fold(f64::INFINITY, f64::min);
    assert!(
        nearest < 0.05,
        "nearest future neighbour {nearest} m from the extrapolation"
    );
}

/// A field that lands every sample on a recorded future twice as fast as the robot may go:
/// raw samples equal the truth (ADE 0, TFS of the truth); guidance lowers Φ by moving them
/// away from it, and the ADE it costs is the displacement it makes.
#[test]
fn guided_windows_measure_guidance_against_the_recorded_future() {
    use human2nav_core::GuidanceWeights;
    use human2nav_core::guidance::analytic::GeodesicTarget;
    let limits = Limits {
        v_max: 1.0,
        v_reverse_max: 0.5,
        a_max: 1.0,
        omega_max: 1.0,
        kappa_max: None,
        lateral_speed_max: 0.1,
        coupled: None,
    };
    let future: Vec<Pose2> = (1..=8)
        .map(|k| Pose2::new(0.2 * k as f64, 0.0, 0.0))
        .collect();
    let model = GeodesicTarget {
        target: future.iter().flat_map(|p| p.to_array()).collect(),
    };
    let window = EvalWindow {
        cond: FlowCondition {
            bev: Vec::new(),
            goal: [3.0, 0.0],
            velocity: [2.0, 0.0],
        },
        future,
        others: Vec::new(),
        others_cv: Vec::new(),
    };
    let phi = Phi::from_weights(&GuidanceWeights::default(), &limits);
    let opts = EvalOptions {
        samples: 3,
        steps: 10,
        ..EvalOptions::default()
    };
    let off = GuidanceSettings {
        enabled: false,
        steps_n: 10,
        ..GuidanceSettings::default()
    };
    let windows = [window.clone(), window];
    let mut calls = 0;
    let raw = guided_windows(&model, &windows, &phi, &limits, &off, &opts, |_| calls += 1).unwrap();
    assert_eq!(calls, 2);
    assert_eq!(raw.windows, 2);
    assert_relative_eq!(raw.ade_raw, 0.0, epsilon = 1e-9);
    assert_relative_eq!(raw.tfs_raw, raw.tfs_human, epsilon = 1e-12);
    assert_relative_eq!(raw.tfs_guided, raw.tfs_raw, epsilon = 1e-12);
    assert_eq!(raw.displacement, 0.0);
    assert_eq!(raw.iterations, 0.0);
    assert!(raw.tfs_human < 1.0, "the truth is too fast for the robot");

    let on = GuidanceSettings {
        enabled: true,
        ..off
    };
    let guided = guided_windows(&model, &windows, &phi, &limits, &on, &opts, |_| ()).unwrap();
    assert!(guided.phi_guided < guided.phi_raw, "{guided:?}");
    assert!(guided.iterations >= 1.0);
    assert!(guided.displacement > 0.0);
    assert_relative_eq!(guided.ade_guided, guided.displacement, epsilon = 1e-9);
    assert!(guided.min_ade_guided <= guided.ade_guided + 1e-12);

    let short = EvalWindow {
        future: vec![Pose2::IDENTITY; 3],
        ..windows[0].clone()
    };
    let err = guided_windows(&model, &[short], &phi, &limits, &on, &opts, |_| ()).unwrap_err();
    assert!(err.to_string().contains("3 future poses"), "{err}");
}

/// A field of zero leaves every sample where the source put it, scattered about the
/// truth (the origin): one sample misses by about √(π/2) of the source's standard
/// deviation, the mean of twenty by about a √20th of that; the early errors score the
/// first second's waypoints only.
#[test]
fn the_samples_mean_is_scored_as_one_forecast() {
    use human2nav_core::guidance::analytic::ConstantField;
    let t = 16;
    let model = ConstantField {
        twists: vec![0.0; 3 * t],
    };
    let mut future = vec![Pose2::IDENTITY; t];
    // The truth leaves the origin after the first second: only the late errors see it.
    for (j, p) in future.iter_mut().enumerate().skip(10) {
        p.x = (j - 9) as f64;
    }
    let window = EvalWindow {
        cond: FlowCondition {
            bev: Vec::new(),
            goal: [0.0, 0.0],
            velocity: [0.0, 0.0],
        },
        future,
        others: Vec::new(),
        others_cv: Vec::new(),
    };
    let opts = EvalOptions {
        samples: 20,
        steps: 2,
        ..EvalOptions::default()
    };
    let m = evaluate(&model, &vec![window; 40], &opts, |_| ()).unwrap();
    assert_eq!(m.early_steps, 10);
    let one = std::f64::consts::FRAC_PI_2.sqrt();
    assert!((m.early_mean_ade - one).abs() < 0.1, "{m:?}");
    assert!(m.early_centroid_ade < 0.45, "{m:?}");
    assert_relative_eq!(m.early_cv_ade, 0.0);
    // Over the whole horizon constant velocity (standing) misses the truth's last six
    // metres: (1 + … + 6) / 16.
    assert_relative_eq!(m.cv_ade, 21.0 / 16.0, epsilon = 1e-12);
    assert_relative_eq!(m.cv_fde, 6.0, epsilon = 1e-12);
    assert!(m.centroid_ade < m.mean_ade, "{m:?}");
    assert!((m.centroid_fde - 6.0).abs() < 0.5, "{m:?}");
}

#[test]
fn errors_of_a_shifted_line() {
    let truth: Vec<Pose2> = (1..=4).map(|j| Pose2::new(j as f64, 0.0, 0.0)).collect();
    let pred: Vec<f64> = (1..=4).flat_map(|j| [j as f64, 0.5, 0.0]).collect();
    let (ade, fde) = displacement_errors(&pred, &truth);
    assert_relative_eq!(ade, 0.5, epsilon = 1e-12);
    assert_relative_eq!(fde, 0.5, epsilon = 1e-12);
}

#[test]
fn constant_velocity_is_linear_in_time() {
    let cv = constant_velocity([1.0, -0.5], 3, 0.1);
    assert_relative_eq!(cv[6], 0.3, epsilon = 1e-12);
    assert_relative_eq!(cv[7], -0.15, epsilon = 1e-12);
    assert_relative_eq!(cv[8], (-0.5f64).atan2(1.0), epsilon = 1e-12);
}

#[test]
fn proximity_uses_same_time_positions() {
    let traj = vec![0.0, 0.0, 0.0, 1.0, 0.0, 0.0];
    // At step 0 the agent is far; at step 1 it sits 0.2 m away.
    let near = vec![vec![Some([5.0, 0.0]), Some([1.0, 0.2])]];
    assert!(comes_close(&traj, &near, 0.3));
    // The same positions at swapped times are not a close approach.
    let swapped = vec![vec![Some([1.0, 0.2]), Some([5.0, 0.0])]];
    assert!(!comes_close(&traj, &swapped, 0.3));
    let unobserved = vec![vec![None, None]];
    assert!(!comes_close(&traj, &unobserved, 0.3));
}

/// A field that walks straight ahead with an empty raster and 1 m to the left of
/// whatever its raster shows: a model that looks at the crowd.
struct Avoids {
    straight: FixedWalk,
    around: FixedWalk,
}

impl Avoids {
    fn new(t: usize) -> Self {
        let walk = |lateral: f64| {
            FixedWalk::along((1..=t).map(|k| Pose2::new(0.1 * k as f64, lateral, 0.0)))
        };
        Self {
            straight: walk(0.0),
            around: walk(1.0),
        }
    }

    fn pick(&self, c: &FlowCondition) -> &FixedWalk {
        if c.bev.iter().any(|v| *v != 0.0) {
            &self.around
        } else {
            &self.straight
        }
    }
}

impl FlowModel for Avoids {
    fn horizon(&self) -> usize {
        self.straight.horizon()
    }
    fn source_std(&self) -> [f64; 3] {
        self.straight.source_std()
    }
    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        self.pick(c).velocity(x, t, c, out)
    }
    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        c: &FlowCondition,
        cot: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        self.pick(c).velocity_vjp(x, t, c, cot, out, vjp)
    }
}

/// The probe tells a model that goes round the person in its raster from one that does
/// not look: the share meeting someone drops with the crowd observed, and the twin samples
/// move apart; a model blind to its raster draws the same samples either way.
#[test]
fn the_crowd_probe_tells_a_model_that_looks_from_one_that_does_not() {
    let t = 16;
    // Someone standing 1 m ahead, on the human's own straight way.
    let standing = vec![[1.0, 0.0]; t];
    let window = EvalWindow {
        cond: FlowCondition {
            bev: vec![0.0, 1.0, 0.0, 0.0],
            goal: [3.0, 0.0],
            velocity: [1.0, 0.0],
        },
        future: (1..=t)
            .map(|k| Pose2::new(0.1 * k as f64, 0.0, 0.0))
            .collect(),
        others: vec![standing.iter().copied().map(Some).collect()],
        others_cv: vec![standing],
    };
    let opts = EvalOptions {
        samples: 4,
        steps: 4,
        ..EvalOptions::default()
    };
    let windows = vec![window; 3];
    let looks = crowd_probe(&Avoids::new(t), &windows, &opts, 0.6, |_| ()).unwrap();
    assert_eq!(looks.windows, 3);
    assert_eq!((looks.observed_recorded, looks.hidden_recorded), (0.0, 1.0));
    assert_eq!((looks.observed_cv, looks.hidden_cv), (0.0, 1.0));
    assert_eq!((looks.human_recorded, looks.human_cv), (1.0, 1.0));
    assert!(looks.displacement > 0.5, "{looks:?}");
    let blind = crowd_probe(&Avoids::new(t).straight, &windows, &opts, 0.6, |_| ()).unwrap();
    assert_eq!(blind.observed_recorded, blind.hidden_recorded);
    assert_eq!(blind.observed_cv, blind.hidden_cv);
    assert_eq!(blind.displacement, 0.0);
}

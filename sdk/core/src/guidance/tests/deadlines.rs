//! Deadlines (module docs, "Deadlines"): a rollout cut short continues at its last velocity,
//! an iteration of Algorithm 1 cut short is undone.

use super::*;

/// A deadline that passes at the `at`-th check (checks come before every network call, so
/// this is "after `at` network calls").
fn after_calls(at: usize) -> Deadline {
    let checks = std::sync::atomic::AtomicUsize::new(0);
    Deadline::from_fn(move || checks.fetch_add(1, std::sync::atomic::Ordering::SeqCst) >= at)
}

#[test]
fn a_rollout_cut_short_continues_at_the_last_velocity() {
    // In a constant field the last velocity is the velocity, so continuing at it is exact.
    let twists: Vec<f64> = [Twist2::new(0.8, 0.1, 0.3); 6]
        .iter()
        .flat_map(|w| w.to_array())
        .collect();
    let model = ConstantField { twists };
    let l = limits(None);
    let c = ctx(&l, Twist2::new(0.5, 0.0, 0.0));
    let phi = Phi::from_weights(&weights(), &l);
    let x0 = source(3, 6, 0.2, 4);
    let settings = GuidanceSettings::default();
    let mut ws = GuidanceWorkspace::new();
    let full = sample_guided(&model, &cond(), &x0, &phi, &c, &settings, &mut ws).unwrap();
    assert_eq!((full.steps_run, full.cut_short), (settings.steps_n, false));
    let cut = sample_guided_until(
        &model,
        &cond(),
        &x0,
        &phi,
        &c,
        &settings,
        &mut ws,
        &after_calls(2),
    )
    .unwrap();
    assert_eq!(
        (cut.steps_run, cut.cut_short, cut.iterations_run),
        (2, true, 0)
    );
    for (a, b) in cut.unguided.iter().zip(&full.unguided) {
        assert!((a - b).abs() < 1e-12, "{a} vs {b}");
    }
    assert_eq!(cut.guided, cut.unguided);
    // A cut rollout is no starting point for guidance.
    assert!(guide_subset(&model, &cond(), &[0], &phi, &c, &settings, &mut ws).is_err());
    // Cut before the first step: no sample at all.
    let none = sample_guided_until(
        &model,
        &cond(),
        &x0,
        &phi,
        &c,
        &settings,
        &mut ws,
        &after_calls(0),
    );
    assert!(matches!(none, Err(GuidanceError::DeadlineBeforeSampling)));
}

#[test]
fn an_iteration_cut_short_is_undone() {
    let l = limits(Some(1.0));
    let c = ctx(&l, Twist2::new(0.5, 0.0, 0.0));
    let phi = Phi::from_weights(&weights(), &l);
    let t = 16;
    let model = LinearField {
        horizon: t,
        a: [[-0.5, 0.0, 0.0], [0.0, -0.5, 0.0], [0.0, 0.0, -0.5]],
        b: [1.5, 0.0, 0.4],
    };
    let x0 = source(3, t, 0.3, 11);
    for variant in [GuidanceVariant::Adaptive, GuidanceVariant::Paper] {
        let one = GuidanceSettings {
            variant,
            iterations_m: 1,
            tolerance: 0.0,
            ..Default::default()
        };
        let n = one.steps_n;
        let per_iteration = if variant == GuidanceVariant::Paper {
            2 * n
        } else {
            2 * n - 1
        };
        let mut ws = GuidanceWorkspace::new();
        let first = sample_guided(&model, &cond(), &x0, &phi, &c, &one, &mut ws).unwrap();
        assert_eq!(first.iterations_run, 1);
        let three = GuidanceSettings {
            iterations_m: 3,
            ..one
        };
        // Cut in the backward pass, then in the forward rollout, of the second iteration.
        for extra in [2, per_iteration - 2] {
            let deadline = after_calls(n + per_iteration + extra);
            let cut =
                sample_guided_until(&model, &cond(), &x0, &phi, &c, &three, &mut ws, &deadline)
                    .unwrap();
            assert_eq!(
                (cut.iterations_run, cut.cut_short),
                (1, true),
                "{variant:?}"
            );
            assert_eq!(
                cut.guided, first.guided,
                "{variant:?}, cut {extra} calls in"
            );
            assert_eq!(cut.phi_after, first.phi_after);
        }
    }
}

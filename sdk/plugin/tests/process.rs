//! Out-of-process plugin instances (`isolation = "process"`): the host survives a plugin that
//! aborts, segfaults or hangs, the failed call names the plugin and the cause, the next call
//! runs in a restarted process, and a well-behaved plugin answers bit for bit as in-process.
//!
//! The fixture library is the cdylib cargo builds for this crate's dev-dependency (next to this
//! test binary); the helper is this crate's `human2nav-plugin-host` binary.

use human2nav_core::constraint::{ConstraintContext, ConstraintError, ConstraintTerm, TrajBatch};
use human2nav_core::{AgentState, Limits, Observation, PlanError, Planner, Pose2, Twist2};
use human2nav_plugin::{PluginError, PluginHost, PluginIsolation, PluginPlanner, process};
use std::time::{Duration, Instant};

mod common;
use common::{fixture, host};

fn obs(time: f64) -> Observation {
    Observation {
        time,
        ego: Pose2::new(0.25, -0.5, 0.1),
        ego_velocity: Twist2::new(0.3, 0.0, 0.05),
        goal: [5.0, 1.0],
        agents: (0..3)
            .map(|j| AgentState {
                id: j,
                position: [1.0 + j as f64 / 3.0, 0.7],
                velocity: [-0.1, 0.2],
                radius: 0.3,
                history: vec![[0.1 * j as f64, 1.0 / 7.0]; j as usize],
            })
            .collect(),
        ..Default::default()
    }
}

fn planner(host: &PluginHost, config: &str, deadline_ms: u64) -> PluginPlanner {
    host.planner_with_options(
        &fixture(),
        "straight",
        config,
        None,
        Some(Duration::from_millis(deadline_ms)),
        PluginIsolation::Process,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

fn limits() -> Limits {
    Limits {
        v_max: 1.2,
        v_reverse_max: 0.4,
        a_max: 1.0,
        omega_max: 1.5,
        kappa_max: Some(2.0),
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

/// A failed call's plan: the stop-in-place fallback with its error.
fn failed_call(p: &mut PluginPlanner, time: f64) -> String {
    let plan = p
        .plan(&obs(time))
        .expect("a failed call still gives a plan");
    assert!(plan.info.fallback);
    assert!(
        plan.poses.iter().all(|q| *q == obs(time).ego),
        "stop in place"
    );
    plan.info.error.expect("the failed call is marked")
}

fn works(p: &mut PluginPlanner, time: f64) -> String {
    let plan = p.plan(&obs(time)).unwrap_or_else(|e| panic!("{e}"));
    assert!(!plan.info.fallback, "{:?}", plan.info);
    assert_eq!(plan.info.error, None);
    plan.info.notes.join(" ")
}

#[test]
fn a_well_behaved_planner_answers_bit_for_bit_as_in_process() {
    let host = host();
    let lib = fixture();
    let config = "horizon = 70\nspeed = 0.7";
    let mut inside = host
        .planner_with_deadline(&lib, "straight", config, None, None)
        .expect("in-process");
    let mut outside = planner(&host, config, 1000);
    assert_eq!(outside.name(), "straight");
    for t in [0.0, 0.1, 0.30000000000000004] {
        let (a, b) = (inside.plan(&obs(t)), outside.plan(&obs(t)));
        let (a, b) = (a.expect("in"), b.expect("out"));
        assert_eq!(a, b);
        for (p, q) in a.poses.iter().zip(&b.poses) {
            assert_eq!(
                [p.x.to_bits(), p.y.to_bits(), p.theta.to_bits()],
                [q.x.to_bits(), q.y.to_bits(), q.theta.to_bits()]
            );
        }
    }
    inside.reset();
    outside.reset();
    assert_eq!(
        inside.plan(&obs(1.0)).expect("in").info.notes,
        outside.plan(&obs(1.0)).expect("out").info.notes
    );
    assert_eq!(outside.process_restarts(), Some(0));
}

#[test]
fn a_well_behaved_constraint_answers_bit_for_bit_as_in_process() {
    let host = host();
    let lib = fixture();
    let inside = host
        .constraint_with_deadline(&lib, "quadratic", "", None, None)
        .expect("in-process");
    let outside = host
        .constraint_with_options(
            &lib,
            "quadratic",
            "",
            None,
            Some(Duration::from_secs(1)),
            PluginIsolation::Process,
        )
        .expect("process");
    let data: Vec<f64> = (0..4 * 32 * 3).map(|i| (i as f64 * 0.37).sin()).collect();
    let limits = limits();
    let o = obs(0.0);
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::new(0.2, 0.0, 0.1),
        agents: &o.agents,
        scene: Default::default(),
    };
    let batch = TrajBatch::new(&data, 4, 32).expect("batch");
    let (mut c1, mut g1) = (vec![0.5; 4], vec![0.25; data.len()]);
    let (mut c2, mut g2) = (c1.clone(), g1.clone());
    inside.evaluate(batch, &ctx, &mut c1, &mut g1).expect("in");
    outside
        .evaluate(batch, &ctx, &mut c2, &mut g2)
        .expect("out");
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&c1), bits(&c2));
    assert_eq!(bits(&g1), bits(&g2));
}

#[test]
fn a_constraint_declares_what_it_is_in_process_and_out_of_it() {
    let host = host();
    let lib = fixture();
    for (config, declared) in [("", false), ("separable_nonnegative = true", true)] {
        for (deadline, isolation) in [
            (None, PluginIsolation::InProcess),
            (Some(Duration::from_secs(1)), PluginIsolation::InProcess),
            (Some(Duration::from_secs(1)), PluginIsolation::Process),
        ] {
            let term = host
                .constraint_with_options(&lib, "quadratic", config, None, deadline, isolation)
                .expect("created");
            assert_eq!(
                term.separable_nonnegative(),
                declared,
                "{config:?} {isolation:?}"
            );
        }
    }
}

#[test]
fn mismatched_buffers_are_refused_before_the_plugin_is_called() {
    let host = host();
    let lib = fixture();
    let inside = host
        .constraint_with_deadline(&lib, "quadratic", "", None, None)
        .expect("in-process");
    let outside = host
        .constraint_with_options(
            &lib,
            "quadratic",
            "",
            None,
            Some(Duration::from_secs(1)),
            PluginIsolation::Process,
        )
        .expect("process");
    let data = vec![0.5; 2 * 4 * 3];
    let limits = limits();
    let ctx = ConstraintContext {
        dt: 0.1,
        limits: &limits,
        initial_velocity: Twist2::ZERO,
        agents: &[],
        scene: Default::default(),
    };
    let good = TrajBatch::new(&data, 2, 4).expect("batch");
    // `TrajBatch`'s fields are public, so a caller can hand over a view that does not add up.
    let odd = TrajBatch {
        data: &data,
        batch: 2,
        horizon: 3,
    };
    for term in [&inside, &outside] {
        let shape = |batch: TrajBatch<'_>, cost: usize, grad: usize| {
            let (mut c, mut g) = (vec![0.0; cost], vec![0.0; grad]);
            match term.evaluate(batch, &ctx, &mut c, &mut g) {
                Err(ConstraintError::Shape(m)) => m,
                other => panic!("expected a shape error, got {other:?}"),
            }
        };
        assert_eq!(
            shape(odd, 2, 24),
            "24 values cannot be 2 trajectories × 3 poses × 3"
        );
        assert_eq!(shape(good, 3, 24), "cost has 3 entries for 2 trajectories");
        assert_eq!(shape(good, 2, 23), "gradient has 23 entries, the batch 24");
        let (mut c, mut g) = (vec![0.0; 2], vec![0.0; 24]);
        term.evaluate(good, &ctx, &mut c, &mut g).expect("good");
    }
}

#[test]
fn the_host_survives_a_planner_that_aborts_and_the_next_call_works() {
    let host = host();
    let mut p = planner(&host, "abort = true\nonly_at_time = 1.0", 1000);
    assert_eq!(works(&mut p, 0.0), "call 1 agents 3 history 3");
    let error = failed_call(&mut p, 1.0);
    assert_eq!(
        error,
        "plugin process for planner `straight` died during `plan`: signal SIGABRT; a new process \
         is started for the next call (3 restarts left)"
    );
    // A fresh instance: its call counter starts again.
    assert_eq!(works(&mut p, 2.0), "call 1 agents 3 history 3");
    assert_eq!(works(&mut p, 2.1), "call 2 agents 3 history 3");
    assert_eq!(p.process_restarts(), Some(1));
    assert!(!p.is_poisoned());
    assert!(host.failures().is_empty());
}

#[test]
fn the_host_survives_a_planner_that_segfaults_and_the_next_call_works() {
    let host = host();
    let mut p = planner(&host, "segfault = true\nonly_at_time = 1.0", 1000);
    works(&mut p, 0.0);
    let error = failed_call(&mut p, 1.0);
    assert_eq!(
        error,
        "plugin process for planner `straight` died during `plan`: signal SIGSEGV; a new process \
         is started for the next call (3 restarts left)"
    );
    works(&mut p, 1.5);
    p.reset();
    works(&mut p, 1.6);
}

#[test]
fn the_host_survives_a_planner_that_hangs_and_the_next_call_works() {
    let host = host();
    let mut p = planner(&host, "hang = true\nonly_at_time = 1.0", 200);
    works(&mut p, 0.0);
    let started = Instant::now();
    let error = failed_call(&mut p, 1.0);
    assert!(started.elapsed() < Duration::from_secs(3));
    assert_eq!(
        error,
        "plugin process for planner `straight` did not answer `plan` within 200 ms (killed); a new \
         process is started for the next call (3 restarts left)"
    );
    works(&mut p, 1.1);
}

#[test]
fn restarts_are_limited_then_the_planner_is_dead() {
    let host = host();
    let mut p = planner(&host, "abort = true", 1000);
    for left in ["3 restarts", "2 restarts", "1 restart"] {
        let e = failed_call(&mut p, 0.0);
        assert!(e.ends_with(&format!("({left} left)")), "{e}");
    }
    let e = failed_call(&mut p, 0.0);
    assert!(
        e.ends_with("no restarts left (at most 3): the instance is marked dead"),
        "{e}"
    );
    assert!(p.is_poisoned());
    assert!(matches!(p.plan(&obs(0.0)), Err(PlanError::Unusable { .. })));
    let failures = host.failures();
    assert_eq!(failures.len(), 1);
    assert!(
        failures[0].instance.starts_with("planner `straight` from ")
            && failures[0].instance.ends_with("(in its own process)"),
        "{failures:?}"
    );
    assert_eq!(p.process_restarts(), Some(process::MAX_RESTARTS));
}

#[test]
fn the_host_survives_a_constraint_that_segfaults_or_aborts() {
    let host = host();
    for (flag, signal) in [("segfault", "SIGSEGV"), ("abort", "SIGABRT")] {
        let term = host
            .constraint_with_options(
                &fixture(),
                "quadratic",
                &format!("{flag} = true\nonly_batch = 2"),
                None,
                Some(Duration::from_secs(1)),
                PluginIsolation::Process,
            )
            .expect("process");
        let limits = limits();
        let ctx = ConstraintContext {
            dt: 0.1,
            limits: &limits,
            initial_velocity: Twist2::ZERO,
            agents: &[],
            scene: Default::default(),
        };
        let data = [0.0, 0.0, 0.0, 1.0, 2.0, 0.0, 0.0, 0.0, 0.0, 1.0, 2.0, 0.0];
        let eval = |batch: usize| {
            let d = &data[..batch * 6];
            let (mut c, mut g) = (vec![0.0; batch], vec![0.0; d.len()]);
            term.evaluate(
                TrajBatch::new(d, batch, 2).expect("batch"),
                &ctx,
                &mut c,
                &mut g,
            )
            .map(|()| c)
        };
        assert_eq!(eval(1).expect("works"), vec![2.5]);
        let e = eval(2).expect_err("crashes");
        assert_eq!(
            e.to_string(),
            format!(
                "constraint `quadratic` failed: plugin process for constraint `quadratic` died \
                 during `evaluate`: signal {signal}; a new process is started for the next call \
                 (3 restarts left)"
            )
        );
        assert_eq!(eval(1).expect("works after the restart"), vec![2.5]);
    }
}

#[test]
fn creation_errors_come_back_from_the_helper() {
    let host = host();
    let err = host
        .planner_with_options(
            &fixture(),
            "no_such_planner",
            "",
            None,
            None,
            PluginIsolation::Process,
        )
        .expect_err("unknown factory");
    assert!(matches!(err, PluginError::Process { .. }), "{err}");
    assert!(err.to_string().contains("no_such_planner"), "{err}");
    let err = host
        .planner_with_options(
            &fixture(),
            "straight",
            "horizon = 0",
            None,
            None,
            PluginIsolation::Process,
        )
        .expect_err("bad config");
    assert!(err.to_string().contains("horizon"), "{err}");
}

#[test]
fn the_helper_is_found_next_to_the_test_binary() {
    // Without a configured path the host looks next to the current executable, then in its
    // parent directory (`target/<profile>/` for this `deps/` binary).
    if std::env::var_os(process::HELPER_ENV).is_some() {
        return;
    }
    let mut p = PluginHost::new()
        .planner_with_options(
            &fixture(),
            "straight",
            "",
            None,
            None,
            PluginIsolation::Process,
        )
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(p.plan(&obs(0.0)).is_ok());
}

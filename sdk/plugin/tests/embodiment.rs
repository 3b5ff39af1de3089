//! Embodiment plugins under a deadline and in a helper process of their own: a well-behaved one
//! answers bit for bit as in process; one that sleeps, panics, answers NaN, aborts or segfaults
//! halts the robot with a failure naming the plugin and the call, and the host lives on.
//!
//! The fixture library is the cdylib cargo builds for this crate's dev-dependency (next to this
//! test binary); the helper is this crate's `human2nav-plugin-host` binary. No assertion here
//! depends on timing: a deadline is tested with a short deadline against a long sleep.

use human2nav_core::embodiment::{Embodiment, RobotState};
use human2nav_core::robot::{PluginIsolation, PluginRef};
use human2nav_core::{ControllerGains, CoupledLimit, Limits, Plan, PlanInfo, Pose2, Twist2};
use human2nav_plugin::{PluginEmbodiment, PluginError, PluginHost, RobotContext};
use std::path::PathBuf;
use std::time::Duration;

mod common;
use common::{fixture, host};

fn robot() -> RobotContext {
    RobotContext {
        limits: Limits {
            v_max: 1.2,
            v_reverse_max: 0.4,
            a_max: 1.0,
            omega_max: 1.5,
            kappa_max: None,
            lateral_speed_max: 0.05,
            coupled: None,
        },
        gains: ControllerGains::default(),
        footprint_radius: 0.3,
    }
}

fn unicycle(
    host: &PluginHost,
    config: &str,
    deadline: Option<Duration>,
    isolation: PluginIsolation,
) -> PluginEmbodiment {
    host.embodiment_with_options(
        &fixture(),
        "unicycle",
        config,
        &robot(),
        deadline,
        isolation,
    )
    .unwrap_or_else(|e| panic!("{e}"))
}

fn state() -> RobotState {
    RobotState {
        pose: Pose2::new(1.0 / 3.0, 2.0, 0.1 + 0.2),
        velocity: Twist2::new(0.7, 0.0, 0.1),
    }
}

fn plan() -> Plan {
    Plan {
        t0: 0.0,
        dt: 0.1,
        poses: vec![Pose2::new(1.0 / 3.0, 2.0, 0.3), Pose2::new(0.4, 2.05, 0.35)],
        info: PlanInfo::default(),
    }
}

/// The robot halted where it was: what a failed `step` gives.
fn halted() -> RobotState {
    RobotState {
        velocity: Twist2::ZERO,
        ..state()
    }
}

/// Every call of the trait, as bits.
fn answers(e: &dyn Embodiment) -> Vec<u64> {
    let s = state();
    let cmd = Twist2::new(1.0 / 3.0, 0.5, -0.25);
    let mut out = vec![u64::from(e.holonomic())];
    let sat = e.saturate(&s, cmd, 0.05);
    let next = e.step(&s, sat, 0.05);
    let track = e.track(&s, &plan(), 0.05);
    for t in [sat, next.velocity, track] {
        out.extend([t.vx, t.vy, t.omega].map(f64::to_bits));
    }
    out.extend([next.pose.x, next.pose.y, next.pose.theta].map(f64::to_bits));
    out
}

#[test]
fn an_embodiment_answers_bit_for_bit_in_process_on_its_worker_and_in_a_helper() {
    let host = host();
    let config = "coupled = [1.0, 0.0, 0.345, 1.4]";
    let direct = unicycle(&host, config, None, PluginIsolation::InProcess);
    let worker = unicycle(
        &host,
        config,
        Some(Duration::from_secs(5)),
        PluginIsolation::InProcess,
    );
    let helper = unicycle(
        &host,
        config,
        Some(Duration::from_secs(5)),
        PluginIsolation::Process,
    );
    assert!(!direct.in_own_process() && !worker.in_own_process());
    assert!(helper.in_own_process());
    assert_eq!(helper.name(), "unicycle");
    let want = Some(CoupledLimit {
        v: 1.0,
        lateral: 0.0,
        omega: 0.345,
        max: 1.4,
    });
    let reference = answers(&direct);
    for e in [&direct, &worker, &helper] {
        assert_eq!(e.coupled_limit(), want);
        assert_eq!(answers(e), reference);
        assert_eq!(e.failure(), None);
    }
    assert!(host.failures().is_empty());
}

#[test]
fn an_embodiment_that_sleeps_in_process_misses_its_deadline_and_halts_the_robot() {
    let host = host();
    let e = unicycle(
        &host,
        "sleep_ms = 600000\nonly_call = \"step\"",
        Some(Duration::from_millis(50)),
        PluginIsolation::InProcess,
    );
    let s = state();
    assert_eq!(
        e.saturate(&s, Twist2::new(1.0, 1.0, 0.2), 0.1),
        Twist2::new(1.0, 0.0, 0.2)
    );
    assert_eq!(e.step(&s, Twist2::new(1.0, 0.0, 0.0), 0.1), halted());
    let failure = e.failure().expect("the missed deadline is recorded");
    assert!(
        failure.starts_with("embodiment `unicycle` from ")
            && failure.contains("did not return from `step` within its deadline of 50 ms"),
        "{failure}"
    );
    // Every later call gives the safe value at once (the worker is still asleep).
    assert_eq!(
        e.saturate(&s, Twist2::new(1.0, 0.0, 0.2), 0.1),
        Twist2::ZERO
    );
    assert_eq!(e.track(&s, &plan(), 0.0), Twist2::ZERO);
    assert!(!e.holonomic());
    let failures = host.failures();
    assert_eq!(failures.len(), 1);
    assert_eq!(failures[0].message, failure);
}

#[test]
fn an_embodiment_that_sleeps_in_its_own_process_is_killed_and_not_restarted() {
    let host = host();
    let e = unicycle(
        &host,
        "sleep_ms = 600000\nonly_call = \"track\"",
        Some(Duration::from_millis(50)),
        PluginIsolation::Process,
    );
    let s = state();
    assert_ne!(e.step(&s, Twist2::new(1.0, 0.0, 0.0), 0.1), halted());
    assert_eq!(e.track(&s, &plan(), 0.0), Twist2::ZERO);
    assert_eq!(
        e.failure().as_deref(),
        Some(
            "plugin process for embodiment `unicycle` did not answer `track` within 50 ms \
             (killed); the instance is marked dead (an embodiment is not restarted)"
        )
    );
    assert_eq!(e.step(&s, Twist2::new(1.0, 0.0, 0.0), 0.1), halted());
    let failures = host.failures();
    assert_eq!(failures.len(), 1);
    assert!(
        failures[0]
            .instance
            .starts_with("embodiment `unicycle` from ")
            && failures[0].instance.ends_with("(in its own process)"),
        "{failures:?}"
    );
}

#[test]
fn the_host_survives_an_embodiment_that_aborts_or_segfaults() {
    let host = host();
    for (flag, signal) in [("abort", "SIGABRT"), ("segfault", "SIGSEGV")] {
        let e = unicycle(
            &host,
            &format!("{flag} = true\nonly_call = \"step\""),
            Some(Duration::from_secs(5)),
            PluginIsolation::Process,
        );
        let s = state();
        assert_eq!(
            e.saturate(&s, Twist2::new(1.0, 1.0, 0.2), 0.1),
            Twist2::new(1.0, 0.0, 0.2)
        );
        assert_eq!(e.step(&s, Twist2::new(1.0, 0.0, 0.0), 0.1), halted());
        assert_eq!(
            e.failure(),
            Some(format!(
                "plugin process for embodiment `unicycle` died during `step`: signal {signal}; \
                 the instance is marked dead (an embodiment is not restarted)"
            ))
        );
        assert_eq!(
            e.saturate(&s, Twist2::new(1.0, 0.0, 0.2), 0.1),
            Twist2::ZERO
        );
    }
    assert_eq!(host.failures().len(), 2);
}

#[test]
fn an_embodiment_that_aborts_while_created_is_an_error_naming_it() {
    let host = host();
    let err = host
        .embodiment_with_options(
            &fixture(),
            "unicycle",
            "abort = true\nonly_call = \"coupled_limit\"",
            &robot(),
            Some(Duration::from_secs(5)),
            PluginIsolation::Process,
        )
        .expect_err("the helper dies");
    assert!(matches!(err, PluginError::Process { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.starts_with("embodiment `unicycle` from ")
            && msg.contains("died while creating the instance: signal SIGABRT"),
        "{msg}"
    );
    // In process, a sleeping `coupled_limit` misses the deadline instead of hanging creation.
    let err = host
        .embodiment_with_options(
            &fixture(),
            "unicycle",
            "sleep_ms = 600000\nonly_call = \"coupled_limit\"",
            &robot(),
            Some(Duration::from_millis(50)),
            PluginIsolation::InProcess,
        )
        .expect_err("no answer in time");
    assert!(
        err.to_string()
            .contains("did not return from `coupled_limit` within its deadline of 50 ms"),
        "{err}"
    );
}

#[test]
fn panics_and_bad_answers_in_a_helper_are_named_like_in_process() {
    let host = host();
    for isolation in [PluginIsolation::InProcess, PluginIsolation::Process] {
        let e = unicycle(
            &host,
            "panic_on_step = true",
            Some(Duration::from_secs(5)),
            isolation,
        );
        assert_eq!(e.step(&state(), Twist2::ZERO, 0.1), halted());
        assert_eq!(
            e.failure().as_deref(),
            Some(
                "embodiment `unicycle`: `step` failed: panicked: unicycle was told to panic \
                 in step; the robot is halted"
            ),
            "{isolation:?}"
        );
        // The fixture passes a NaN command through `saturate`: the answer is refused.
        let e = unicycle(&host, "", Some(Duration::from_secs(5)), isolation);
        let nan = Twist2::new(f64::NAN, 0.0, 0.0);
        assert_eq!(e.saturate(&state(), nan, 0.1), Twist2::ZERO);
        let failure = e.failure().expect("refused");
        assert!(
            failure.starts_with("embodiment `unicycle`: saturate answered vx = NaN"),
            "{isolation:?}: {failure}"
        );
    }
}

#[test]
fn a_profile_reference_runs_in_a_helper_unless_it_says_in_process() {
    let host = host();
    let reference = |isolation| PluginRef {
        library: fixture(),
        plugin: "unicycle".into(),
        config: String::new(),
        weight: 1.0,
        deadline_ms: Some(250.0),
        isolation,
        declared_in: PathBuf::from("robot.toml"),
    };
    let e = host
        .embodiment_ref(&reference(None), &robot())
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(e.in_own_process());
    assert_eq!(e.deadline(), Some(Duration::from_millis(250)));
    let e = host
        .embodiment_ref(&reference(Some(PluginIsolation::InProcess)), &robot())
        .unwrap_or_else(|e| panic!("{e}"));
    assert!(!e.in_own_process());
    let e = host
        .embodiment_ref(
            &PluginRef {
                deadline_ms: Some(-1.0),
                ..reference(None)
            },
            &robot(),
        )
        .expect_err("a bad deadline");
    assert!(e.to_string().contains("deadline_ms"), "{e}");
}

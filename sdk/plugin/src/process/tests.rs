use super::*;

#[test]
fn observations_and_plans_round_trip_bit_for_bit() {
    let obs = Observation {
        time: 0.1 + 0.2,
        ego: Pose2::new(1.0 / 3.0, -0.0, f64::MIN_POSITIVE),
        ego_velocity: Twist2::new(0.5, 1e-300, -2.0),
        goal: [5.0, 1.0],
        agents: vec![AgentState {
            id: 7,
            position: [1.0, 2.0],
            velocity: [0.1, -0.2],
            radius: 0.3,
            history: vec![[0.5, 0.25]; 3],
        }],
        obstacles: vec![
            Obstacle::Circle {
                center: [1.0, -2.0],
                radius: 0.4,
            },
            Obstacle::Segment {
                a: [0.0, 1.5],
                b: [9.0, 1.5],
            },
            Obstacle::Polygon {
                vertices: vec![[3.0, 0.0], [4.0, 0.0], [4.0, 1.0]],
            },
        ],
        occupancy: Some(OccupancyGrid {
            origin: Pose2::new(-5.0, -5.0, 0.0),
            resolution: 0.05,
            width: 2,
            height: 2,
            data: vec![-1, 0, 100, 64],
            occupied_threshold: 65,
        }),
        ..Default::default()
    };
    let mut e = Enc::default();
    encode_observation(&mut e, &obs);
    let msg = e.finish().to_vec();
    let mut d = Dec::new(&msg[5..]);
    let back = decode_observation(&mut d).expect("decode");
    assert_eq!(back, obs);
    assert_eq!(back.ego.y.to_bits(), (-0.0f64).to_bits());

    let plan = Plan {
        t0: 0.3,
        dt: 0.1,
        poses: vec![Pose2::new(0.1, 0.2, 0.3); 4],
        info: PlanInfo {
            fallback: true,
            notes: vec!["a".into(), "b c".into()],
            error: Some("why".into()),
            ..PlanInfo::default()
        },
    };
    encode_plan_answer(&mut e, &Ok(plan.clone()));
    let msg = e.finish().to_vec();
    let back = decode_plan_answer(&mut Dec::new(&msg[4..])).expect("decode");
    assert_eq!(back.expect("ok"), plan);
    let err = PlanError::Failed {
        planner: "p".into(),
        message: "m".into(),
    };
    encode_plan_answer(&mut e, &Err(err));
    let msg = e.finish().to_vec();
    let back = decode_plan_answer(&mut Dec::new(&msg[4..])).expect("decode");
    assert_eq!(back.expect_err("err").to_string(), "planner `p` failed: m");
}

#[test]
fn short_or_lying_messages_are_errors() {
    let mut e = Enc::default();
    e.start(ANSWER_OK);
    e.u64(1 << 60);
    let msg = e.finish().to_vec();
    let mut d = Dec::new(&msg[5..]);
    assert!(d.count(8).is_err());
    let mut d = Dec::new(&msg[5..7]);
    assert!(d.u64().is_err());
}

#[test]
fn signals_are_named() {
    assert_eq!(signal_name(11), "signal SIGSEGV");
    assert_eq!(signal_name(6), "signal SIGABRT");
    assert_eq!(signal_name(64), "signal 64");
}

#[test]
fn embodiment_calls_and_answers_round_trip_bit_for_bit() {
    let state = RobotState {
        pose: Pose2::new(1.0 / 3.0, -0.0, 0.1 + 0.2),
        velocity: Twist2::new(0.5, 1e-300, -2.0),
    };
    let plan = Plan {
        t0: 0.3,
        dt: 0.1,
        poses: vec![
            Pose2::new(0.1, 0.2, 0.3),
            Pose2::new(f64::MIN_POSITIVE, 0.5, -1.0),
        ],
        info: PlanInfo::default(),
    };
    let calls = [
        EmbodimentCall::Holonomic,
        EmbodimentCall::Saturate {
            state,
            cmd: Twist2::new(1.0, 0.0, 0.25),
            dt: 0.05,
        },
        EmbodimentCall::Step {
            state,
            cmd: Twist2::new(-0.1, 0.0, 1.0 / 7.0),
            dt: 0.05,
        },
        EmbodimentCall::Track {
            state,
            plan: Cow::Borrowed(&plan),
            t: 0.35,
        },
        EmbodimentCall::CoupledLimit,
    ];
    let mut e = Enc::default();
    for call in &calls {
        call.encode(&mut e);
        let msg = e.finish().to_vec();
        let mut d = Dec::new(&msg[4..]);
        let op = d.u8().expect("op");
        let back = EmbodimentCall::decode(op, &mut d)
            .expect("decodes")
            .expect("an embodiment call");
        assert_eq!(&back, call);
    }
    assert_eq!(
        EmbodimentCall::decode(OP_PLAN, &mut Dec::new(&[])).expect("no error"),
        None
    );

    let coupled = CoupledLimit {
        v: 1.0,
        lateral: 0.0,
        omega: 0.345,
        max: 1.4,
    };
    let answers = [
        (&calls[0], EmbodimentValue::Holonomic(true), None),
        (
            &calls[1],
            EmbodimentValue::Twist(Twist2::new(0.1, -0.0, 1e-7)),
            Some("why"),
        ),
        (&calls[2], EmbodimentValue::State(state), None),
        (&calls[3], EmbodimentValue::Twist(Twist2::ZERO), None),
        (
            &calls[4],
            EmbodimentValue::CoupledLimit(Some(coupled)),
            None,
        ),
        (&calls[4], EmbodimentValue::CoupledLimit(None), None),
    ];
    for (call, value, failure) in answers {
        encode_embodiment_answer(&mut e, &value, failure);
        let msg = e.finish().to_vec();
        let (back, why) =
            decode_embodiment_answer(&mut Dec::new(&msg[4..]), call).expect("decodes");
        assert_eq!(back, value);
        assert_eq!(why.as_deref(), failure);
    }
    // A coupled limit the host would refuse in process is refused from the helper too.
    let bad = CoupledLimit {
        max: -1.0,
        ..coupled
    };
    encode_embodiment_answer(&mut e, &EmbodimentValue::CoupledLimit(Some(bad)), None);
    let msg = e.finish().to_vec();
    let err = decode_embodiment_answer(&mut Dec::new(&msg[4..]), &calls[4]).expect_err("bad");
    assert!(err.starts_with("coupled_limit: max = "), "{err}");
}

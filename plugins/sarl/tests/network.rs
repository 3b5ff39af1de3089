//! The value network, the state rotation, the action space and the look-ahead against hand
//! computations.

// Helpers outside #[test] functions unwrap too (clippy.toml only allows it inside tests).
#![allow(clippy::unwrap_used)]

use approx::assert_relative_eq;
use human2nav_sarl::action::ActionSpace;
use human2nav_sarl::env::{RewardConfig, lookahead_reward};
use human2nav_sarl::net::{NetConfig, SarlNet};
use human2nav_sarl::policy::{LookAhead, empty_world_value, select_action};
use human2nav_sarl::state::{HumanState, JOINT_DIM, RobotState, push_joint_states, rotate};
use proptest::prelude::*;
use std::f64::consts::{E, PI};
use tch::{Device, Kind, Tensor};

fn net() -> SarlNet {
    SarlNet::seeded(&NetConfig::default(), 3, Device::Cpu).unwrap()
}

/// `[b, n, 13]` states with entries drawn from a seeded generator; as in real joint states,
/// the robot's own part (the first 6 entries) is the same in every row of a state.
fn states(b: i64, n: i64, seed: u64) -> Tensor {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut v = Vec::new();
    for _ in 0..b {
        let own: Vec<f32> = (0..6).map(|_| rng.random_range(-2.0..2.0)).collect();
        for _ in 0..n {
            v.extend_from_slice(&own);
            v.extend((6..JOINT_DIM).map(|_| rng.random_range(-2.0f32..2.0)));
        }
    }
    Tensor::from_slice(&v).reshape([b, n, JOINT_DIM as i64])
}

#[test]
fn attention_weights_sum_to_one() {
    let net = net();
    for n in [1, 2, 5, 13] {
        let out = net.forward_full(&states(7, n, n as u64));
        assert_eq!(out.attention.size(), vec![7, n]);
        assert_eq!(out.value.size(), vec![7, 1]);
        let sums =
            Vec::<f32>::try_from(&out.attention.sum_dim_intlist(1, false, Kind::Float)).unwrap();
        for s in sums {
            assert_relative_eq!(s, 1.0, epsilon = 1e-6);
        }
        let w = Vec::<f32>::try_from(&out.attention.reshape([-1])).unwrap();
        assert!(w.iter().all(|x| *x > 0.0 && *x < 1.0 + 1e-6));
    }
}

#[test]
fn one_human_gets_all_the_attention() {
    let out = net().forward_full(&states(4, 1, 11));
    let w = Vec::<f32>::try_from(&out.attention.reshape([-1])).unwrap();
    for x in w {
        assert_relative_eq!(x, 1.0, epsilon = 1e-7);
    }
}

#[test]
fn parameter_count_matches_the_documented_sizes() {
    let net = net();
    let n: i64 = net
        .var_store()
        .variables()
        .values()
        .map(Tensor::numel)
        .map(|x| x as i64)
        .sum();
    assert_eq!(n as usize, NetConfig::default().parameter_count());
    // mlp1 13·150+150 + 150·100+100, mlp2 100·100+100 + 100·50+50, attention
    // 200·100+100 + 100·100+100 + 100+1, mlp3 56·150+150 + 150·100+100 + 100·100+100 + 100+1.
    assert_eq!(n, 17_200 + 15_150 + 30_301 + 33_851);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// Permuting the humans permutes the attention weights the same way and leaves the value
    /// unchanged.
    #[test]
    fn attention_is_permutation_equivariant(seed in 0u64..1000, n in 2i64..8, shift in 1i64..7) {
        let net = net();
        let x = states(3, n, seed);
        let perm: Vec<i64> = (0..n).map(|i| (i + shift) % n).collect();
        let xp = x.index_select(1, &Tensor::from_slice(&perm));
        let a = net.forward_full(&x);
        let b = net.forward_full(&xp);
        let wa = a.attention.index_select(1, &Tensor::from_slice(&perm));
        let diff = (wa - &b.attention).abs().max().double_value(&[]);
        prop_assert!(diff < 1e-6, "attention differs by {diff}");
        let dv = (a.value - b.value).abs().max().double_value(&[]);
        prop_assert!(dv < 1e-5, "value differs by {dv}");
    }
}

#[test]
fn value_is_permutation_invariant_for_real_joint_states() {
    let net = net();
    let robot = RobotState {
        px: 0.5,
        py: -3.0,
        vx: 0.2,
        vy: 0.7,
        radius: 0.3,
        gx: 0.0,
        gy: 4.0,
        v_pref: 1.0,
        theta: 0.0,
    };
    let humans: Vec<HumanState> = (0..5)
        .map(|i| HumanState {
            px: i as f64 - 2.0,
            py: 0.3 * i as f64,
            vx: 0.1 * i as f64,
            vy: -0.5,
            radius: 0.3,
        })
        .collect();
    let mut a = Vec::new();
    push_joint_states(&robot, &humans, true, &mut a);
    let mut rev = humans.clone();
    rev.reverse();
    let mut b = Vec::new();
    push_joint_states(&robot, &rev, true, &mut b);
    let va = net.values(&a, 1, 5).unwrap()[0];
    let vb = net.values(&b, 1, 5).unwrap()[0];
    assert_relative_eq!(va, vb, epsilon = 1e-5);
}

#[test]
fn rotation_hand_case() {
    // Robot at the origin with its goal 4 m to the north: the rotated x axis points north and
    // the y axis west. The robot moves north at 1 m/s; a human at (1, 1) walks west at 0.5 m/s.
    let robot = RobotState {
        px: 0.0,
        py: 0.0,
        vx: 0.0,
        vy: 1.0,
        radius: 0.3,
        gx: 0.0,
        gy: 4.0,
        v_pref: 1.2,
        theta: 0.3,
    };
    let human = HumanState {
        px: 1.0,
        py: 1.0,
        vx: -0.5,
        vy: 0.0,
        radius: 0.25,
    };
    let s = rotate(&robot, &human, true);
    let expected = [
        4.0,         // dg
        1.2,         // v_pref
        0.0,         // theta (holonomic)
        0.3,         // radius
        1.0,         // vx: straight ahead
        0.0,         // vy
        1.0,         // px1: 1 m ahead
        -1.0,        // py1: 1 m to the right (east = −y')
        0.0,         // vx1: walking west is across
        0.5,         // vy1: toward +y' (west)
        0.25,        // radius1
        2f64.sqrt(), // da
        0.55,        // radius_sum
    ];
    for (a, b) in s.iter().zip(expected) {
        assert_relative_eq!(f64::from(*a), b, epsilon = 1e-6, max_relative = 1e-6);
    }
    // A unicycle keeps its heading relative to the goal direction: 0.3 − π/2.
    let s = rotate(&robot, &human, false);
    assert_relative_eq!(f64::from(s[2]), 0.3 - PI / 2.0, epsilon = 1e-6);
}

#[test]
fn action_space_matches_crowdnav() {
    let a = ActionSpace::crowdnav(1.0);
    assert_eq!(a.len(), 81);
    assert_eq!(a.actions[0], [0.0, 0.0]);
    assert_eq!(a.speeds.len(), 5);
    assert_eq!(a.headings.len(), 16);
    for (k, v) in a.speeds.iter().enumerate() {
        let i = (k + 1) as f64;
        assert_relative_eq!(*v, ((i / 5.0).exp() - 1.0) / (E - 1.0), epsilon = 1e-12);
    }
    assert_relative_eq!(a.speeds[4], 1.0, epsilon = 1e-12);
    assert_relative_eq!(a.speeds[0], 0.128851, epsilon = 1e-6);
    for (j, h) in a.headings.iter().enumerate() {
        assert_relative_eq!(*h, 2.0 * PI * j as f64 / 16.0, epsilon = 1e-12);
    }
    // Heading-major: action 1 + 5·j + k moves at speeds[k] along headings[j].
    let v = a.speeds[2] * 1.5;
    let b = ActionSpace::crowdnav(1.5);
    let act = b.actions[1 + 5 * 4 + 2];
    assert_relative_eq!(act[0], v * (PI / 2.0).cos(), epsilon = 1e-12);
    assert_relative_eq!(act[1], v, epsilon = 1e-12);
    // Every action is distinct and none is faster than v_pref.
    for (i, x) in b.actions.iter().enumerate() {
        assert!(x[0].hypot(x[1]) <= 1.5 + 1e-12);
        for y in &b.actions[..i] {
            assert!((x[0] - y[0]).abs() + (x[1] - y[1]).abs() > 1e-9);
        }
    }
}

#[test]
fn look_ahead_values_are_reward_plus_discounted_value() {
    let net = net();
    let actions = ActionSpace::crowdnav(1.0);
    let la = LookAhead {
        gamma: 0.9,
        time_step: 0.25,
        reward: RewardConfig::default(),
    };
    assert_relative_eq!(la.gamma_bar(1.0), 0.9f64.powf(0.25), epsilon = 1e-15);
    let robot = RobotState {
        px: 0.0,
        py: 3.5,
        vx: 0.0,
        vy: 0.5,
        radius: 0.3,
        gx: 0.0,
        gy: 4.0,
        v_pref: 1.0,
        theta: 0.0,
    };
    // One human close to the east, walking west into the robot.
    let humans = [HumanState {
        px: 0.9,
        py: 3.5,
        vx: -1.0,
        vy: 0.0,
        radius: 0.3,
    }];
    let d = select_action(&net, &actions, &robot, &humans, &la).unwrap();
    assert_eq!(d.action_values.len(), 81);
    for (i, a) in actions.actions.iter().enumerate() {
        let next = robot.propagate(*a, 0.25);
        let nh = [humans[0].propagate(0.25)];
        let (r, _) = lookahead_reward(&next, &nh, 0.25, &la.reward);
        let mut s = Vec::new();
        push_joint_states(&next, &nh, true, &mut s);
        let v = net.values(&s, 1, 1).unwrap()[0];
        assert_relative_eq!(
            d.action_values[i],
            r + la.gamma_bar(1.0) * f64::from(v),
            epsilon = 1e-5
        );
    }
    let best = d
        .action_values
        .iter()
        .copied()
        .fold(f64::NEG_INFINITY, f64::max);
    assert_eq!(d.action_values[d.index], best);
    assert_eq!(d.velocity, actions.actions[d.index]);
    // Full speed north (heading π/2) reaches the goal: reward +1.
    let north = 1 + 5 * 4 + 4;
    let (r, done) = lookahead_reward(
        &robot.propagate(actions.actions[north], 0.25),
        &[humans[0].propagate(0.25)],
        0.25,
        &la.reward,
    );
    assert_eq!((r, done), (1.0, true));
    // Full speed east runs into the human: −0.25.
    let east = 1 + 4;
    let (r, done) = lookahead_reward(
        &robot.propagate(actions.actions[east], 0.25),
        &[humans[0].propagate(0.25)],
        0.25,
        &la.reward,
    );
    assert_eq!((r, done), (-0.25, true));
}

#[test]
fn without_humans_the_closed_form_value_drives_at_the_goal() {
    let net = net();
    let la = LookAhead {
        gamma: 0.9,
        time_step: 0.25,
        reward: RewardConfig::default(),
    };
    // Goal 3 m to the north-east (heading π/4, one of the 16 headings).
    let robot = RobotState {
        px: 1.0,
        py: 1.0,
        vx: 0.0,
        vy: 0.0,
        radius: 0.3,
        gx: 1.0 + 3.0 * std::f64::consts::FRAC_1_SQRT_2,
        gy: 1.0 + 3.0 * std::f64::consts::FRAC_1_SQRT_2,
        v_pref: 1.2,
        theta: 0.0,
    };
    let g = la.gamma_bar(1.2);
    // V₀ = γ̄^{(d − r)/(Δt·v_pref)}.
    assert_relative_eq!(
        empty_world_value(&robot, &la),
        g.powf((3.0 - 0.3) / (0.25 * 1.2)),
        max_relative = 1e-12
    );
    let actions = ActionSpace::crowdnav(1.2);
    let d = select_action(&net, &actions, &robot, &[], &la).unwrap();
    let ne = 1 + 5 * 2 + 4;
    assert_eq!(d.index, ne, "{:?}", d.velocity);
    // After one step at 1.2 m/s the goal is 2.7 m away: value 0 + γ̄·γ̄^{(2.7 − 0.3)/0.3}.
    assert_relative_eq!(
        d.action_values[ne],
        g * g.powf((2.7 - 0.3) / 0.3),
        max_relative = 1e-6
    );
}

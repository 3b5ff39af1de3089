//! The shipped policy in circle crossing against the straight-to-goal policy on the same
//! held-out seeds (outcome rates only; nothing is timed). Needs `models/sarl` (committed).

// Helpers outside #[test] functions unwrap too (clippy.toml only allows it inside tests).
#![allow(clippy::unwrap_used)]

use human2nav_sarl::SarlModel;
use human2nav_sarl::action::ActionSpace;
use human2nav_sarl::eval::{Policy, SeedStream, evaluate};
use std::path::Path;

#[test]
fn the_shipped_policy_beats_straight_to_goal() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/sarl");
    let model = SarlModel::load_dir(&dir).unwrap_or_else(|e| {
        panic!(
            "the shipped SARL model in {} does not load ({e}); train it with \
             `human2nav baseline train-sarl --config sdk/configs/sarl.toml`",
            dir.display()
        )
    });
    let env = model.card.env.clone();
    let actions = ActionSpace::crowdnav(env.robot_v_pref);
    let sarl = Policy::Sarl {
        net: &model.net,
        actions: &actions,
        lookahead: model.lookahead(),
        epsilon: 0.0,
    };
    let seed = model.card.training.seed;
    let n = 100;
    let s = evaluate(&env, &sarl, seed, SeedStream::Test, n, &mut |_| {}).unwrap();
    let st = evaluate(
        &env,
        &Policy::Straight,
        seed,
        SeedStream::Test,
        n,
        &mut |_| {},
    )
    .unwrap();
    eprintln!(
        "circle crossing, {n} held-out seeds: SARL success {:.2} collision {:.2} timeout {:.2}; straight success {:.2} collision {:.2}",
        s.success_rate, s.collision_rate, s.timeout_rate, st.success_rate, st.collision_rate
    );
    assert_eq!(s.episodes, n);
    assert!(
        s.success_rate >= st.success_rate + 0.3,
        "SARL success {} vs straight {}",
        s.success_rate,
        st.success_rate
    );
    assert!(s.collision_rate < st.collision_rate);
    // The card's numbers were measured on a superset of these seeds with the same code.
    assert!(model.card.evaluation.episodes >= n);
}

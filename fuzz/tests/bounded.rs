//! The bounded run: every target on a fixed seed for `HUMAN2NAV_FUZZ_CASES` cases (default
//! 256), or for `HUMAN2NAV_FUZZ_SECONDS` seconds. A panic in a reader fails its test. The
//! `model` targets need the default feature of that name (libtorch); `plugin_observation` needs
//! the plugin libraries built (`cargo build --workspace`); the `capi_*` targets need the shipped
//! Diablo profile, planner.toml and model.

use human2nav_fuzz::{run_bounded, targets};

fn run(name: &str) {
    let t = targets::by_name(name).expect("target exists");
    let n = run_bounded(&t);
    assert!(n > 0);
}

macro_rules! bounded {
    ($($name:ident),* $(,)?; model: $($model:ident),* $(,)?) => {
        $(#[test]
        fn $name() {
            run(stringify!($name));
        })*

        $(#[cfg(feature = "model")]
        #[test]
        fn $model() {
            run(stringify!($model));
        })*

        #[test]
        fn every_target_has_a_test() {
            #[allow(unused_mut)]
            let mut tested = vec![$(stringify!($name)),*];
            #[cfg(feature = "model")]
            tested.extend([$(stringify!($model)),*]);
            let mut all: Vec<_> = targets::all().iter().map(|t| t.name).collect();
            tested.sort_unstable();
            all.sort_unstable();
            assert_eq!(tested, all);
        }
    };
}

bounded!(
    robot_toml,
    urdf,
    data_toml,
    bench_toml,
    guidance_toml,
    planner_toml,
    eth_obsmat,
    homography,
    ucy_vsp,
    sgan,
    sdd_raw,
    sdd_scales,
    trajnet,
    episodes_json,
    plugin_file,
    plugin_entry,
    plugin_vtable,
    tuple_cache,
    plugin_observation,
    capi_create,
    capi_plan;
    model: model_card,
    planner_config,
    train_toml,
    scaling_toml,
    sarl_toml,
);

/// The observation target reaches both plugins (not only the host's input checks): over the
/// bounded run's inputs, some plans come back and some constraint calls evaluate, and some
/// inputs are refused.
#[test]
fn observations_reach_the_plugins() {
    use human2nav_fuzz::targets::observe::run_observation;
    let t = targets::by_name("plugin_observation").expect("target exists");
    let seeds = (t.seeds)();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(17);
    let (mut planned, mut evaluated, n) = (0, 0, 256);
    let mut errors = std::collections::BTreeSet::new();
    for _ in 0..n {
        let r = run_observation(&human2nav_fuzz::next_input(&mut rng, &seeds));
        planned += usize::from(r.planned);
        evaluated += usize::from(r.evaluated);
        errors.extend(r.plan_error.map(|e| e.chars().take(80).collect::<String>()));
    }
    assert!(
        planned > 0 && planned < n && evaluated > 0 && evaluated < n,
        "{planned} plans and {evaluated} evaluations of {n} inputs; planner errors: {errors:#?}"
    );
    eprintln!("plugin_observation: {planned} plans, {evaluated} evaluations of {n} inputs");
}

/// The C API target gets both outcomes: plans that come back (and are read) and observations
/// the library refuses with a message.
#[test]
fn capi_plans_and_refuses() {
    use human2nav_fuzz::targets::capi::run_plan;
    let t = targets::by_name("capi_plan").expect("target exists");
    let seeds = (t.seeds)();
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(51);
    let (mut planned, n) = (0, 128);
    let mut refusals = std::collections::BTreeSet::new();
    for _ in 0..n {
        let r = run_plan(&human2nav_fuzz::next_input(&mut rng, &seeds));
        planned += usize::from(r.status == Some(human2nav_c::h2n_status::Ok));
        refusals.extend(r.message);
    }
    assert!(
        planned > 0 && planned < n,
        "{planned} plans of {n} inputs; refusals: {refusals:#?}"
    );
    eprintln!("capi_plan: {planned} plans of {n} inputs");
}

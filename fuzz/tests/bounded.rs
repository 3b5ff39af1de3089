//! The bounded run: every target on a fixed seed for `HUMAN2NAV_FUZZ_CASES` cases (default
//! 256), or for `HUMAN2NAV_FUZZ_SECONDS` seconds. A panic in a reader fails its test. The
//! `model` targets need the default feature of that name (libtorch); `plugin_observation` needs
//! the plugin libraries built (`cargo build --workspace`).

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
    plugin_observation;
    model: model_card,
    planner_config,
);

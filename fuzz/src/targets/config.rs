//! Robot profiles, URDFs and the configuration TOMLs that core, data and sim parse.

use super::{lossy, seeds_of};
use crate::{Scratch, Target};
use human2nav_core::guidance::GuidanceSettings;
use human2nav_core::human2nav::Human2NavSettings;
use human2nav_core::robot::RobotProfile;

const ROBOT_TOMLS: [&str; 4] = [
    include_str!("../../../robots/ackermann/robot.toml"),
    include_str!("../../../robots/diablo/robot.toml"),
    include_str!("../../../robots/go2/robot.toml"),
    include_str!("../../../robots/tracked/robot.toml"),
];

/// `(file name the profiles use, text)`.
const URDFS: [(&str, &str); 4] = [
    (
        "ackermann.urdf",
        include_str!("../../../robots/ackermann/ackermann.urdf"),
    ),
    (
        "diablo.urdf",
        include_str!("../../../robots/diablo/diablo.urdf"),
    ),
    ("go2.urdf", include_str!("../../../robots/go2/go2.urdf")),
    (
        "tracked.urdf",
        include_str!("../../../robots/tracked/tracked.urdf"),
    ),
];

const BENCH_TOMLS: [&str; 5] = [
    include_str!("../../../sdk/configs/bench.toml"),
    include_str!("../../../sdk/configs/bench_baselines.toml"),
    include_str!("../../../sdk/configs/bench_sarl.toml"),
    include_str!("../../../sdk/configs/bench_synthetic.toml"),
    include_str!("../../../sdk/configs/bench_val.toml"),
];

pub(crate) fn targets() -> Vec<Target> {
    vec![
        Target {
            name: "robot_toml",
            covers: "robot.toml (the four shipped profiles) through RobotProfile::load, then its \
                     built-in embodiment and limit table",
            seeds: || seeds_of(&ROBOT_TOMLS),
            exec: robot_toml,
        },
        Target {
            name: "urdf",
            covers: "the four shipped URDFs under their own robot.toml through RobotProfile::load \
                     (footprint, base link, nesting check)",
            seeds: || {
                URDFS
                    .iter()
                    .enumerate()
                    .map(|(i, (_, u))| {
                        let mut b = vec![i as u8];
                        b.extend_from_slice(u.as_bytes());
                        b
                    })
                    .collect()
            },
            exec: urdf,
        },
        Target {
            name: "data_toml",
            covers: "sdk/configs/data.toml through DataConfig::load",
            seeds: || seeds_of(&[include_str!("../../../sdk/configs/data.toml")]),
            exec: data_toml,
        },
        Target {
            name: "bench_toml",
            covers: "the five sdk/configs/bench*.toml through BenchConfig::load (with a `base` \
                     file beside it)",
            seeds: || seeds_of(&BENCH_TOMLS),
            exec: bench_toml,
        },
        Target {
            name: "guidance_toml",
            covers: "sdk/configs/guidance.toml through GuidanceSettings::from_toml_str",
            seeds: || seeds_of(&[include_str!("../../../sdk/configs/guidance.toml")]),
            exec: guidance_toml,
        },
        Target {
            name: "planner_toml",
            covers: "sdk/configs/planner.toml's [human2nav] table as Human2NavSettings + validate",
            seeds: || seeds_of(&[include_str!("../../../sdk/configs/planner.toml")]),
            exec: planner_toml,
        },
    ]
}

/// Writes the shipped URDFs beside the profile (once per scratch directory).
fn shipped_urdfs(s: &Scratch) {
    for (name, text) in URDFS {
        if !s.dir().join(name).is_file() {
            s.write(name, text.as_bytes());
        }
    }
}

fn use_profile(p: &RobotProfile) {
    let _ = p.builtin_embodiment();
    let _ = p.limit_table();
}

fn robot_toml(s: &Scratch, input: &[u8]) {
    shipped_urdfs(s);
    let path = s.write("robot.toml", input);
    if let Ok(p) = RobotProfile::load(&path) {
        use_profile(&p);
    }
}

fn urdf(s: &Scratch, input: &[u8]) {
    let (which, body) = input.split_first().unwrap_or((&0, &[]));
    let i = usize::from(*which) % URDFS.len();
    s.write(URDFS[i].0, body);
    let path = s.write("robot.toml", ROBOT_TOMLS[i].as_bytes());
    if let Ok(p) = RobotProfile::load(&path) {
        use_profile(&p);
    }
}

fn data_toml(s: &Scratch, input: &[u8]) {
    let path = s.write("data.toml", input);
    let _ = human2nav_data::config::DataConfig::load(&path);
}

fn bench_toml(s: &Scratch, input: &[u8]) {
    // `bench_val.toml` names `base = "sdk/configs/bench.toml"`, resolved against the directory
    // (no workspace above the scratch directory).
    if !s.dir().join("sdk/configs/bench.toml").is_file() {
        s.write("sdk/configs/bench.toml", BENCH_TOMLS[0].as_bytes());
    }
    let path = s.write("bench_fuzz.toml", input);
    if let Ok(cfg) = human2nav_sim::config::BenchConfig::load(&path) {
        let _ = cfg.snapshot_method();
    }
}

fn guidance_toml(_: &Scratch, input: &[u8]) {
    let _ = GuidanceSettings::from_toml_str(&lossy(input));
}

fn planner_toml(_: &Scratch, input: &[u8]) {
    let Ok(table) = lossy(input).parse::<toml::Table>() else {
        return;
    };
    let Some(h) = table.get("human2nav") else {
        return;
    };
    if let Ok(settings) = h.clone().try_into::<Human2NavSettings>() {
        let _ = settings.validate();
    }
}

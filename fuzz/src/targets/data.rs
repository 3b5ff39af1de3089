//! Dataset loaders (ETH, UCY, sgan, SDD raw and TrajNet, scales, homographies), each followed
//! by the resampling every loaded scene goes through, and episode files.
//!
//! The seeds are a few rows in each format, written here (no dataset file is copied).

use super::seeds_of;
use crate::{Scratch, Target};
use human2nav_data::loaders::{eth, sdd, sgan, ucy};
use human2nav_data::resample::{ResampleOptions, resample};
use human2nav_data::{Homography, RawScene};

const OBSMAT: &str = "\
   7.8000000e+02   1.0000000e+00   8.4568443e+00   0.0000000e+00   3.5880664e+00   1.6717144e+00   0.0000000e+00   1.7629183e-01
   7.8600000e+02   1.0000000e+00   9.1255301e+00   0.0000000e+00   3.6585832e+00   1.6628772e+00   0.0000000e+00   3.2672255e-01
   7.9200000e+02   1.0000000e+00   9.7871460e+00   0.0000000e+00   3.8494445e+00   1.6833339e+00   0.0000000e+00   3.7108399e-01
   7.9200000e+02   2.0000000e+00   2.1000000e+00   0.0000000e+00   5.0000000e+00  -1.2000000e+00   0.0000000e+00   0.0000000e+00
   7.9800000e+02   2.0000000e+00   1.6000000e+00   0.0000000e+00   5.1000000e+00  -1.2000000e+00   0.0000000e+00   1.0000000e-01
   8.0400000e+02   2.0000000e+00   1.1000000e+00   0.0000000e+00   5.2000000e+00  -1.2000000e+00   0.0000000e+00   1.0000000e-01
";

const ETH_H: &str = "\
   2.8128700e-02   2.0091900e-03  -4.6693600e+00
   8.0625700e-04   2.5195500e-02  -5.0608800e+00
   3.4555400e-04   9.2512200e-05   4.6255300e-01
";

const ZARA_H: [[f64; 3]; 3] = [
    [-0.025956517, 0.0, 7.838868],
    [-0.0010953874, 0.02166433, 5.5660456],
    [0.0, 0.0, 1.0],
];

const VSP: &str = "\
2 - the number of splines
3 - Num of control points
279.000000 -123.000000 0 87.397438 - (2D point, m_id)
218.000000 -123.000000 25 90.000000 - (2D point, m_id)
148.000000 -118.000000 55 84.382416 - (2D point, m_id)
2 - Num of control points
-61.000000 -157.000000 143 90.000000 - (2D point, m_id)
15.000000 -151.000000 170 91.145760
";

const SGAN: &str = "780\t1.0\t8.46\t3.59\n790\t1.0\t9.57\t3.79\n800\t1.0\t10.67\t3.99\n\
                    790\t2.0\t1.00\t2.00\n800\t2.0\t1.40\t2.10\n810\t2.0\t1.80\t2.20\n";

const SDD_RAW: &str = "\
0 793 1035 835 1097 6500 0 0 0 \"Pedestrian\"
0 795 1030 837 1092 6501 0 0 1 \"Pedestrian\"
0 797 1025 839 1087 6502 0 1 1 \"Pedestrian\"
1 100 200 140 260 6500 0 0 0 \"Biker\"
1 104 200 144 260 6501 1 0 0 \"Biker\"
2 400 400 420 430 6500 0 0 0 \"Pedestrian\"
2 402 401 422 431 6530 0 0 0 \"Pedestrian\"
";

const SDD_SCALES: &str = "\
bookstore:
   video0:
      scale: 0.038392063
      certainty: 1.0
   video1:
      scale: 0.039892913
      certainty: 1.0
gates:   # comment
   video2:
      scale: 0.04062433
";

const TRAJNET: &str = "0 100 1.728 14.378\n12 100 2.035 14.378\n24 100 2.342 14.378\n\
                       0 101 5.0 3.0\n12 101 4.8 3.1\n24 101 4.6 3.2\n";

pub(crate) fn targets() -> Vec<Target> {
    vec![
        Target {
            name: "eth_obsmat",
            covers: "eth::load_obsmat + resample",
            seeds: || seeds_of(&[OBSMAT]),
            exec: eth_obsmat,
        },
        Target {
            name: "homography",
            covers: "H.txt through Homography::load (ETH and UCY), then both directions",
            seeds: || seeds_of(&[ETH_H]),
            exec: homography,
        },
        Target {
            name: "ucy_vsp",
            covers: "ucy::load_vsp (zara H, both vsp conventions) + resample",
            seeds: || seeds_of(&[VSP]),
            exec: ucy_vsp,
        },
        Target {
            name: "sgan",
            covers: "sgan::load (`biwi_eth` 15 fps and 25 fps names) + resample",
            seeds: || seeds_of(&[SGAN]),
            exec: sgan_file,
        },
        Target {
            name: "sdd_raw",
            covers: "sdd::load_raw (annotations.txt) + resample",
            seeds: || seeds_of(&[SDD_RAW]),
            exec: sdd_raw,
        },
        Target {
            name: "sdd_scales",
            covers: "sdd::SddScales::load (estimated_scales.yaml) and scale lookup",
            seeds: || seeds_of(&[SDD_SCALES]),
            exec: sdd_scales,
        },
        Target {
            name: "trajnet",
            covers: "sdd::load_trajnet + resample",
            seeds: || seeds_of(&[TRAJNET]),
            exec: trajnet,
        },
        Target {
            name: "episodes_json",
            covers: "episode files (a suite or one episode) through sim's load_episode_file",
            seeds: episode_seeds,
            exec: episodes_json,
        },
        Target {
            name: "tuple_cache",
            covers: "a tuple cache (manifest.json and train/val/test.bin, parts of one input) \
                     through TupleCache::open, load_compact, load (rasters) and pick_scenes",
            seeds: cache_seeds,
            exec: tuple_cache,
        },
    ]
}

/// Separates the parts of a `tuple_cache` input: the manifest, then one file per split.
const PART: &[u8] = b"\n--8<--\n";

/// A cache of two scenes (train and test) with a few tuples each, as `TupleCache::write` writes
/// it, as one input.
fn cache_seeds() -> Vec<Vec<u8>> {
    use human2nav_data::tuples::{CompactTuple, Split, TupleOptions, TupleStats};
    use human2nav_data::{Manifest, SceneInfo, TupleCache};
    let Ok(scratch) = Scratch::new("cache-seed") else {
        return Vec::new();
    };
    let scene = |name: &str, split| SceneInfo {
        name: format!("eth/{name}"),
        dataset: "eth".into(),
        format: "eth".into(),
        split,
        duration: 12.0,
        tracks: 3,
        tuples: 2,
        median_speed: Some(1.2),
        skipped: Default::default(),
    };
    let tuple = |scene: u16, k: usize| CompactTuple {
        scene,
        class: None,
        goal: [3.0, 0.5 * k as f32],
        velocity: [1.0, 0.0],
        future: (1..=4)
            .map(|i| [0.1 * i as f32, 0.0, 0.01 * k as f32])
            .collect(),
        agents: (0..k)
            .map(|a| [1.0 + a as f32, -0.5, 0.3, 0.0, 0.3])
            .collect(),
    };
    let manifest = Manifest {
        version: human2nav_data::cache::CACHE_VERSION,
        source: "real".into(),
        bev: Default::default(),
        horizon: 4,
        dt: 0.1,
        tuples: TupleOptions::default(),
        scenes: vec![scene("hotel", Split::Train), scene("univ", Split::Test)],
        counts: Default::default(),
        stats: TupleStats::default(),
        file_bytes: Default::default(),
    };
    let splits = [
        (Split::Train, vec![tuple(0, 0), tuple(0, 2)]),
        (Split::Val, Vec::new()),
        (Split::Test, vec![tuple(1, 3)]),
    ];
    let dir = scratch.dir().join("cache");
    if TupleCache::write(&dir, manifest, &splits).is_err() {
        return Vec::new();
    }
    let mut input = std::fs::read(dir.join("manifest.json")).unwrap_or_default();
    for split in Split::ALL {
        input.extend_from_slice(PART);
        input.extend(std::fs::read(dir.join(format!("{}.bin", split.name()))).unwrap_or_default());
    }
    vec![input]
}

fn tuple_cache(s: &Scratch, input: &[u8]) {
    use human2nav_data::TupleCache;
    use human2nav_data::tuples::Split;
    let mut parts = Vec::new();
    let mut rest = input;
    while let Some(at) = rest.windows(PART.len()).position(|w| w == PART) {
        parts.push(&rest[..at]);
        rest = &rest[at + PART.len()..];
    }
    parts.push(rest);
    let dir = s.dir().join("cache");
    let _ = std::fs::remove_dir_all(&dir);
    s.write("cache/manifest.json", parts[0]);
    for (split, bytes) in Split::ALL.iter().zip(parts.iter().skip(1)) {
        s.write(&format!("cache/{}.bin", split.name()), bytes);
    }
    let Ok(cache) = TupleCache::open(&dir) else {
        return;
    };
    for split in Split::ALL {
        if let Ok(tuples) = cache.load_compact(split) {
            let _ = TupleCache::class_counts(&tuples);
            // Dense rasters of small splits only (each is 3·H·W floats).
            if tuples.len() <= 64 {
                let _ = cache.load(split);
            }
        }
        let _ = cache.pick_scenes(split, 0.5, 7);
    }
}

fn resampled(scene: Result<RawScene, human2nav_data::DataError>) {
    if let Ok(raw) = scene {
        let _ = resample(&raw, &ResampleOptions::default());
    }
}

fn eth_obsmat(s: &Scratch, input: &[u8]) {
    resampled(eth::load_obsmat(&s.write("obsmat.txt", input), "eth/eth"));
}

fn homography(s: &Scratch, input: &[u8]) {
    if let Ok(h) = Homography::load(&s.write("H.txt", input)) {
        for p in [[0.0, 0.0], [320.0, 240.0], [1e6, -1e6]] {
            if let Some(w) = h.image_to_world(p) {
                let _ = h.world_to_image(w);
            }
        }
        let _ = h.det();
    }
}

fn ucy_vsp(s: &Scratch, input: &[u8]) {
    let path = s.write("annotation.vsp", input);
    let Some(h) = Homography::new(ZARA_H) else {
        return;
    };
    for conv in [ucy::VspConvention::ImageRowCol, ucy::VspConvention::Centred] {
        resampled(ucy::load_vsp(&path, &h, conv, "ucy/zara01"));
    }
}

fn sgan_file(s: &Scratch, input: &[u8]) {
    let name = if input.len() % 2 == 0 {
        "biwi_eth.txt"
    } else {
        "crowds_zara01.txt"
    };
    resampled(sgan::load(&s.write(name, input), "eth/eth", "eth"));
}

fn sdd_raw(s: &Scratch, input: &[u8]) {
    let path = s.write("annotations.txt", input);
    let opts = sdd::SddRawOptions {
        pedestrians_only: input.len() % 2 == 0,
        keep_occluded: input.len() % 3 != 0,
    };
    resampled(sdd::load_raw(&path, 0.0406, "sdd/gates_2", &opts));
}

fn sdd_scales(s: &Scratch, input: &[u8]) {
    if let Ok(sc) = sdd::SddScales::load(&s.write("estimated_scales.yaml", input)) {
        for v in ["bookstore_0", "gates_2", ""] {
            let _ = sc.scale(v);
        }
    }
}

fn trajnet(s: &Scratch, input: &[u8]) {
    resampled(sdd::load_trajnet(
        &s.write("bookstore_0.txt", input),
        "sdd/bookstore_0",
    ));
}

/// A suite of two short synthetic episodes and one episode alone, as the writers produce them.
fn episode_seeds() -> Vec<Vec<u8>> {
    let Ok(mut eps) = human2nav_sim::config::synthetic_episodes(1, 7) else {
        return Vec::new();
    };
    eps.truncate(2);
    for e in &mut eps {
        e.agents.truncate(2);
        for a in &mut e.agents {
            a.positions.truncate(4);
        }
    }
    let mut out = Vec::new();
    if let Ok(one) = serde_json::to_vec_pretty(&eps[0]) {
        out.push(one);
    }
    let suite = human2nav_data::EpisodeSuite::new("synthetic", eps);
    if let Ok(all) = serde_json::to_vec_pretty(&suite) {
        out.push(all);
    }
    out
}

fn episodes_json(s: &Scratch, input: &[u8]) {
    if let Ok(suite) = human2nav_sim::episode::load_episode_file(&s.write("episodes.json", input)) {
        for e in &suite.episodes {
            let _ = (e.steps(), e.goal_distance());
        }
    }
}

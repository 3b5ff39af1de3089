//! Loader tests on the real files (skipped when the datasets are absent) and on bad input.

#![allow(clippy::unwrap_used)]

mod common;

use approx::assert_relative_eq;
use human2nav_data::loaders::{eth, sdd, sgan, ucy};
use human2nav_data::resample::{median, resample};
use human2nav_data::{AgentClass, DataError, RawScene, RawTrack, ResampleOptions, Sample};

/// Median speed (m/s) of the resampled samples moving faster than 0.2 m/s.
fn walking_speed(raw: &RawScene) -> f64 {
    let scene = resample(raw, &ResampleOptions::default());
    median(scene.speeds(0.2)).unwrap()
}

fn assert_walking(raw: &RawScene) {
    let v = walking_speed(raw);
    eprintln!("{}: median walking speed {v:.3} m/s", raw.name);
    assert!(
        (0.8..=1.8).contains(&v),
        "{}: median walking speed {v:.3} m/s",
        raw.name
    );
}

#[test]
fn eth_obsmat_metres_and_time_step() {
    let Some(root) = common::data("eth_obsmat_metres_and_time_step") else {
        return;
    };
    let dir = root.join("eth_ucy/opentraj_raw/ETH");
    for (seq, rows, peds) in [("seq_eth", 8908, 360), ("seq_hotel", 6544, 390)] {
        let raw = eth::load_obsmat(&dir.join(seq).join("obsmat.txt"), seq).unwrap();
        assert_eq!(raw.tracks.len(), peds, "{seq}");
        assert_eq!(raw.sample_count(), rows, "{seq}");
        // Consecutive annotations of a pedestrian are 0.4 s apart in both sequences.
        let t = &raw.tracks[0].samples;
        assert_relative_eq!(t[1].t - t[0].t, 0.4, epsilon = 1e-9);
        assert_walking(&raw);
    }
    // First row of seq_eth: pos_x = 8.4568443, pos_y (column 5) = 3.5880664.
    let raw = eth::load_obsmat(&dir.join("seq_eth/obsmat.txt"), "eth").unwrap();
    assert_relative_eq!(raw.tracks[0].samples[0].p[0], 8.4568443, epsilon = 1e-9);
    assert_relative_eq!(raw.tracks[0].samples[0].p[1], 3.5880664, epsilon = 1e-9);
}

#[test]
fn eth_homography_round_trip_and_image_bounds() {
    let Some(root) = common::data("eth_homography_round_trip_and_image_bounds") else {
        return;
    };
    let dir = root.join("eth_ucy/opentraj_raw/ETH");
    // (row, col) image bounds of the two cameras: 480×640 and 576×720.
    for (seq, rows, cols) in [("seq_eth", 480.0, 640.0), ("seq_hotel", 576.0, 720.0)] {
        let h = eth::load_homography(&dir.join(seq), seq).unwrap();
        let raw = eth::load_obsmat(&dir.join(seq).join("obsmat.txt"), seq).unwrap();
        let mut worst = 0.0f64;
        for s in raw.tracks.iter().flat_map(|t| &t.samples) {
            let px = h.world_to_image(s.p).unwrap();
            assert!(
                px[0] > -5.0 && px[0] < rows + 5.0 && px[1] > -5.0 && px[1] < cols + 5.0,
                "{seq}: {px:?}"
            );
            let back = h.image_to_world(px).unwrap();
            worst = worst
                .max((back[0] - s.p[0]).abs())
                .max((back[1] - s.p[1]).abs());
        }
        assert!(worst < 1e-9, "{seq}: round trip error {worst:e} m");
        // And image → world → image on a pixel grid.
        for r in (0..rows as usize).step_by(37) {
            for c in (0..cols as usize).step_by(41) {
                let w = h.image_to_world([r as f64, c as f64]).unwrap();
                let px = h.world_to_image(w).unwrap();
                assert_relative_eq!(px[0], r as f64, epsilon = 1e-7);
                assert_relative_eq!(px[1], c as f64, epsilon = 1e-7);
            }
        }
    }
    let err = eth::load_homography(&dir, "nowhere").unwrap_err();
    assert!(matches!(err, DataError::MissingHomography { .. }), "{err}");
    assert!(err.to_string().contains("H.txt"));
}

#[test]
fn ucy_vsp_splines_through_homography() {
    let Some(root) = common::data("ucy_vsp_splines_through_homography") else {
        return;
    };
    let ucy_root = root.join("eth_ucy/opentraj_raw/UCY");
    let mut pooled = Vec::new();
    for (scene, splines, points) in [
        ("zara01", 148, 1520),
        ("zara02", 204, 2375),
        ("zara03", 137, 1505),
        ("students01", 415, 6173),
        ("students03", 434, 5779),
        ("uni_examples", 118, 1085),
    ] {
        let path = ucy_root.join(scene).join("annotation.vsp");
        let parsed = ucy::parse_vsp(&path).unwrap();
        assert_eq!(parsed.len(), splines, "{scene}");
        assert_eq!(
            parsed.iter().map(Vec::len).sum::<usize>(),
            points,
            "{scene}"
        );
        let h = ucy::load_homography(&ucy_root, scene).unwrap();
        let raw = ucy::load_vsp(&path, &h, ucy::VspConvention::of(scene), scene).unwrap();
        let v = walking_speed(&raw);
        eprintln!("{scene}: median walking speed {v:.3} m/s");
        // The students scenes are slow crowds (the authors' own metric obsmat agrees).
        assert!((0.55..=1.8).contains(&v), "{scene}: {v}");
        pooled.extend(resample(&raw, &ResampleOptions::default()).speeds(0.2));
    }
    let v = median(pooled).unwrap();
    eprintln!("UCY pooled median walking speed {v:.3} m/s");
    assert!(
        (0.8..=1.8).contains(&v),
        "UCY pooled median walking speed {v}"
    );
    let err = ucy::load_homography(&ucy_root, "arxiepiskopi").unwrap_err();
    assert!(matches!(err, DataError::MissingHomography { .. }), "{err}");
}

#[test]
fn zara_vsp_through_h_reproduces_the_authors_obsmat() {
    let Some(root) = common::data("zara_vsp_through_h_reproduces_the_authors_obsmat") else {
        return;
    };
    let ucy_root = root.join("eth_ucy/opentraj_raw/UCY");
    let h = ucy::load_homography(&ucy_root, "zara01").unwrap();
    let splines = ucy::parse_vsp(&ucy_root.join("zara01/annotation.vsp")).unwrap();
    let obs = eth::load_obsmat(&ucy_root.join("zara01/obsmat.txt"), "zara01").unwrap();
    // obsmat frames are 1-based (frame f ↔ vsp frame f − 1), 0.04 s per frame at step 10.
    let (mut n, mut worst) = (0, 0.0f64);
    for (i, cps) in splines.iter().enumerate() {
        let Some(track) = obs.tracks.iter().find(|t| t.id == i as u64 + 1) else {
            continue;
        };
        for cp in cps {
            let t = (cp.frame + 1) as f64 * 0.04;
            let Some(s) = track.samples.iter().find(|s| (s.t - t).abs() < 1e-6) else {
                continue;
            };
            let w = h
                .image_to_world(ucy::VspConvention::ImageRowCol.image_point(cp.x, cp.y))
                .unwrap();
            worst = worst.max((w[0] - s.p[0]).hypot(w[1] - s.p[1]));
            n += 1;
        }
    }
    eprintln!("zara01: {n} control points matched, worst error {worst:.2e} m");
    assert!(n > 100, "only {n} control points matched");
    assert!(worst < 1e-3, "worst error {worst} m");
}

#[test]
fn sgan_benchmark_files_and_the_biwi_eth_time_step() {
    let Some(root) = common::data("sgan_benchmark_files_and_the_biwi_eth_time_step") else {
        return;
    };
    let dir = root.join("eth_ucy/trajectron_sgan_format/raw/all_data");
    let mut pooled = Vec::new();
    for (file, rows, peds) in [
        ("biwi_eth", 5492, 360),
        ("biwi_hotel", 6543, 389),
        ("crowds_zara01", 5153, 148),
        ("crowds_zara02", 9722, 204),
        ("crowds_zara03", 5005, 137),
        ("students001", 21813, 415),
        ("students003", 17953, 434),
        ("uni_examples", 2747, 118),
    ] {
        let raw = sgan::load(&dir.join(format!("{file}.txt")), file, "sgan").unwrap();
        assert_eq!(raw.sample_count(), rows, "{file}");
        assert_eq!(raw.tracks.len(), peds, "{file}");
        let v = walking_speed(&raw);
        eprintln!("{file}: median walking speed {v:.3} m/s");
        assert!((0.55..=1.8).contains(&v), "{file}: {v}");
        pooled.extend(resample(&raw, &ResampleOptions::default()).speeds(0.2));
    }
    let v = median(pooled).unwrap();
    assert!(
        (0.8..=1.8).contains(&v),
        "benchmark pooled median walking speed {v}"
    );
    // biwi_eth rows are 10 ETH frames (15 fps) apart: 0.667 s, not 0.4 s.
    let path = dir.join("biwi_eth.txt");
    assert_relative_eq!(sgan::frame_rate(&path), 15.0);
    let raw = sgan::load(&path, "biwi_eth", "sgan").unwrap();
    let s = &raw.tracks[0].samples;
    assert_relative_eq!(s[1].t - s[0].t, 10.0 / 15.0, epsilon = 1e-9);
    // Same positions as the original obsmat at the same time (README: median error 0.004 m).
    let obs = eth::load_obsmat(
        &root.join("eth_ucy/opentraj_raw/ETH/seq_eth/obsmat.txt"),
        "eth",
    )
    .unwrap();
    let mut errs = Vec::new();
    for t in raw.tracks.iter().take(50) {
        let Some(o) = obs.tracks.iter().find(|o| o.id == t.id) else {
            continue;
        };
        for s in &t.samples {
            if let Some(w) = o
                .samples
                .windows(2)
                .find(|w| w[0].t <= s.t && s.t <= w[1].t)
            {
                let u = (s.t - w[0].t) / (w[1].t - w[0].t);
                let p = [
                    w[0].p[0] + u * (w[1].p[0] - w[0].p[0]),
                    w[0].p[1] + u * (w[1].p[1] - w[0].p[1]),
                ];
                errs.push((p[0] - s.p[0]).hypot(p[1] - s.p[1]));
            }
        }
    }
    let med = median(errs).unwrap();
    assert!(med < 0.02, "biwi_eth vs obsmat median error {med} m");
}

#[test]
fn sdd_raw_boxes_scales_and_pedestrian_filter() {
    let Some(root) = common::data("sdd_raw_boxes_scales_and_pedestrian_filter") else {
        return;
    };
    let base = root.join("sdd/opentraj_raw");
    let scales = sdd::SddScales::load(&base.join("estimated_scales.yaml")).unwrap();
    assert_eq!(scales.scales.len(), 60);
    assert_relative_eq!(scales.scale("gates_4").unwrap(), 0.04412268, epsilon = 1e-9);
    let err = scales.scale("gates_99").unwrap_err();
    assert!(
        matches!(err, DataError::MissingScale { .. }) && err.to_string().contains("gates_99"),
        "{err}"
    );
    // README: gates/video4 has 45 pedestrian tracks; track 44 at frame 0 is (939.5, 1546) px.
    let path = base.join("gates/video4/annotations.txt");
    let raw = sdd::load_raw(
        &path,
        scales.scale("gates_4").unwrap(),
        "sdd/gates_4",
        &sdd::SddRawOptions::default(),
    )
    .unwrap();
    let rows = sdd::parse_raw(&path).unwrap();
    let ids = |c: Option<human2nav_data::AgentClass>| {
        let mut v: Vec<u64> = rows
            .iter()
            .filter(|r| c.is_none_or(|c| r.class == c))
            .map(|r| r.track_id)
            .collect();
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    assert_eq!(rows.len(), 76132);
    assert_eq!(ids(Some(human2nav_data::AgentClass::Pedestrian)), 45);
    assert_eq!(ids(None), 45 + 53 + 13);
    // Tracks whose every row is `lost` vanish.
    let lost_only = |c: bool| {
        let mut v: Vec<u64> = rows
            .iter()
            .filter(|r| !r.lost && (!c || r.class == human2nav_data::AgentClass::Pedestrian))
            .map(|r| r.track_id)
            .collect();
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    assert_eq!(raw.tracks.len(), lost_only(true));
    assert!(raw.tracks.len() >= 40);
    let t44 = raw.tracks.iter().find(|t| t.id == 44).unwrap();
    let s0 = t44.samples.iter().find(|s| s.t == 0.0).unwrap();
    assert_relative_eq!(s0.p[0], 41.453, epsilon = 1e-3);
    assert_relative_eq!(s0.p[1], -68.214, epsilon = 1e-3);
    assert!(raw.dropped.iter().any(|(w, n)| w == "lost_rows" && *n > 0));
    let all = sdd::load_raw(
        &path,
        0.04412268,
        "sdd/gates_4",
        &sdd::SddRawOptions {
            pedestrians_only: false,
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!(all.tracks.len(), lost_only(false));
    // Every raw video: median walking speed of pedestrians.
    let (mut n, mut pooled, mut outliers) = (0, Vec::new(), Vec::new());
    for scene_dir in std::fs::read_dir(&base).unwrap().flatten() {
        for video in std::fs::read_dir(scene_dir.path())
            .into_iter()
            .flatten()
            .flatten()
        {
            let ann = video.path().join("annotations.txt");
            if !ann.is_file() {
                continue;
            }
            let name = format!(
                "{}_{}",
                scene_dir.file_name().to_string_lossy(),
                video
                    .file_name()
                    .to_string_lossy()
                    .trim_start_matches("video")
            );
            let raw = sdd::load_raw(
                &ann,
                scales.scale(&name).unwrap(),
                &name,
                &Default::default(),
            )
            .unwrap();
            let v = walking_speed(&raw);
            eprintln!("sdd {name}: median walking speed {v:.3} m/s");
            if !(0.8..=1.8).contains(&v) {
                outliers.push(name.clone());
            }
            pooled.extend(resample(&raw, &ResampleOptions::default()).speeds(0.2));
            n += 1;
        }
    }
    assert_eq!(n, 19);
    // quad_3's eight "pedestrians" move at ≈ 3 m/s (68 px/s at 0.0444 m/px); all others walk.
    assert!(
        outliers.len() <= 1,
        "videos with implausible speeds: {outliers:?}"
    );
    let v = median(pooled).unwrap();
    eprintln!("SDD raw pooled median walking speed {v:.3} m/s");
    assert!(
        (0.8..=1.8).contains(&v),
        "SDD raw pooled median walking speed {v}"
    );
}

#[test]
fn sdd_trajnet_chunks_in_metres() {
    let Some(root) = common::data("sdd_trajnet_chunks_in_metres") else {
        return;
    };
    let base = root.join("sdd/trajnet_split_socialvae");
    let (mut rows, mut walks, mut joined) = (0, 0, 0);
    for split in ["train", "test"] {
        for f in std::fs::read_dir(base.join(split)).unwrap().flatten() {
            let raw = sdd::load_trajnet(&f.path(), &f.file_name().to_string_lossy()).unwrap();
            // Walks of whole 20-row chunks, each continuing the last at the files' step.
            for t in &raw.tracks {
                assert_eq!(t.samples.len() % 20, 0, "{}: walk {}", raw.name, t.id);
                assert!(
                    t.samples
                        .windows(2)
                        .all(|w| (w[1].t - w[0].t - sdd::TRAJNET_STEP).abs() < 1e-9),
                    "{}: walk {} skips a step",
                    raw.name,
                    t.id
                );
            }
            rows += raw.sample_count();
            walks += raw.tracks.len();
            joined += raw
                .dropped
                .iter()
                .find(|(why, _)| why == "chunks_joined")
                .map_or(0, |(_, n)| *n);
        }
    }
    // Every row is kept and every chunk is either a walk's first or joined to one.
    let chunks = 8_494 + 2_829;
    assert_eq!(rows, 169_880 + 56_580);
    assert_eq!(walks + joined, chunks);
    eprintln!("SDD TrajNet: {chunks} chunks joined into {walks} walks");
    // Most chunks continue another: 8 s chunks of walks that last longer.
    assert!(joined * 10 > chunks * 6, "{joined} of {chunks} joined");
    let raw = sdd::load_trajnet(&base.join("train/gates_4.txt"), "gates_4").unwrap();
    let t = raw.tracks.iter().find(|t| t.id == 47).unwrap();
    assert_relative_eq!(t.samples[0].p[0], 41.45325786, epsilon = 1e-9);
    assert_relative_eq!(t.samples[0].p[1], -68.21366328, epsilon = 1e-9);
    assert_relative_eq!(t.samples[1].t - t.samples[0].t, 0.4, epsilon = 1e-9);
    // Pooled over the test videos the walking speed is plausible.
    let mut speeds = Vec::new();
    for f in std::fs::read_dir(base.join("test")).unwrap().flatten() {
        let raw = sdd::load_trajnet(&f.path(), "x").unwrap();
        speeds.extend(resample(&raw, &ResampleOptions::default()).speeds(0.2));
    }
    let v = median(speeds).unwrap();
    assert!((0.8..=1.8).contains(&v), "trajnet test median speed {v}");
}

#[test]
fn malformed_and_non_finite_lines_name_file_and_line() {
    let p = common::scratch("bad_obsmat.txt");
    std::fs::write(&p, "1 1 1.0 0 2.0 0 0 0\n7 1 1.0 0 oops 0 0 0\n").unwrap();
    let err = eth::load_obsmat(&p, "bad").unwrap_err();
    assert!(matches!(err, DataError::Parse { line: 2, .. }), "{err}");
    assert!(err.to_string().contains("bad_obsmat.txt:2"), "{err}");

    let p = common::scratch("nan.txt");
    std::fs::write(&p, "0 1 1.0 2.0\n10 1 NaN 2.0\n").unwrap();
    let err = sgan::load(&p, "nan", "sgan").unwrap_err();
    assert!(matches!(err, DataError::NonFinite { line: 2, .. }), "{err}");
    std::fs::write(&p, "0 1 1.0 inf\n").unwrap();
    assert!(matches!(
        sgan::load(&p, "inf", "sgan").unwrap_err(),
        DataError::NonFinite { line: 1, .. }
    ));

    let p = common::scratch("short.vsp");
    std::fs::write(
        &p,
        "2 - splines\n2 - points\n1 2 0 0\n3 4 10 0\n3 - points\n1 2 0 0\n",
    )
    .unwrap();
    let err = ucy::parse_vsp(&p).unwrap_err();
    assert!(err.to_string().contains("short.vsp"), "{err}");

    let p = common::scratch("ann.txt");
    std::fs::write(
        &p,
        "0 1 2 3 4 5 0 0 0 \"Pedestrian\"\n0 1 2 3 4 6 2 0 0 \"Pedestrian\"\n",
    )
    .unwrap();
    let err = sdd::parse_raw(&p).unwrap_err();
    assert!(matches!(err, DataError::Parse { line: 2, .. }), "{err}");
    std::fs::write(&p, "0 1 2 3 4 5 0 0 0 \"Dragon\"\n").unwrap();
    assert!(
        sdd::parse_raw(&p)
            .unwrap_err()
            .to_string()
            .contains("Dragon")
    );

    let p = common::scratch("H.txt");
    std::fs::write(&p, "1 0 0\n0 1 0\n").unwrap();
    assert!(human2nav_data::Homography::load(&p).is_err());
    std::fs::write(&p, "1 2 0\n2 4 0\n0 0 0\n").unwrap();
    assert!(matches!(
        human2nav_data::Homography::load(&p).unwrap_err(),
        DataError::SingularHomography { .. }
    ));
}

#[test]
fn trajnet_chunks_of_one_walk_are_joined_and_others_are_not() {
    // Frames at 30 fps, a row every 12 frames (0.4 s). Walker A walks +x at 1 m/s in two chunks
    // (ids 5, 9); chunk 9 starts one step after chunk 5 ends, where A's last step puts it.
    // Chunk 7 also starts then, but 2 m away: someone else. Chunk 3 starts where A would be,
    // but two steps late: not a continuation either.
    let row = |frame: i64, id: u64, x: f64, y: f64| format!("{frame} {id} {x} {y}\n");
    let mut body = String::new();
    for k in 0..20 {
        body += &row(12 * k, 5, 0.4 * k as f64, 0.0);
    }
    for k in 20..40 {
        body += &row(12 * k, 9, 0.4 * k as f64 + 0.03, 0.0);
        body += &row(12 * k, 7, 0.4 * k as f64, 2.0);
    }
    for k in 41..61 {
        body += &row(12 * k, 3, 0.4 * k as f64, 0.0);
    }
    let p = common::scratch("trajnet_chunks.txt");
    std::fs::write(&p, body).unwrap();
    let raw = sdd::load_trajnet(&p, "chunks").unwrap();
    let ids: Vec<u64> = raw.tracks.iter().map(|t| t.id).collect();
    assert_eq!(
        ids,
        vec![3, 5, 7],
        "walk 5 absorbs chunk 9 and keeps its id"
    );
    let walk = &raw.tracks[1];
    assert_eq!(walk.samples.len(), 40);
    assert_relative_eq!(walk.samples[20].t - walk.samples[19].t, 0.4, epsilon = 1e-9);
    assert_relative_eq!(walk.samples[39].p[0], 0.4 * 39.0 + 0.03, epsilon = 1e-9);
    assert_eq!(
        raw.dropped,
        vec![("chunks_joined".to_string(), 1)],
        "one chunk joined, no rows lost"
    );
    assert_eq!(raw.sample_count(), 80);
    // The same rows in another id order give the same walks.
    let mut lines: Vec<String> = std::fs::read_to_string(&p)
        .unwrap()
        .lines()
        .map(str::to_string)
        .collect();
    lines.reverse();
    std::fs::write(&p, lines.join("\n")).unwrap();
    assert_eq!(sdd::load_trajnet(&p, "chunks").unwrap().tracks, raw.tracks);
}

#[test]
fn of_two_chunks_that_could_continue_a_walk_the_nearer_one_does() {
    // Walk 1 ends at x = 7.6 heading +x at 1 m/s; chunks 2 (0.3 m off) and 4 (0.1 m off) both
    // start one step later within the join distance. Chunk 4 continues it, chunk 2 stays a walk.
    let mut chunks = vec![RawTrack {
        id: 1,
        class: AgentClass::Pedestrian,
        samples: (0..20)
            .map(|k| Sample {
                t: 0.4 * k as f64,
                p: [0.4 * k as f64, 0.0],
            })
            .collect(),
    }];
    for (id, dy) in [(2, 0.3), (4, 0.1)] {
        chunks.push(RawTrack {
            id,
            class: AgentClass::Pedestrian,
            samples: (20..40)
                .map(|k| Sample {
                    t: 0.4 * k as f64,
                    p: [0.4 * k as f64, dy],
                })
                .collect(),
        });
    }
    let (walks, joined) = sdd::join_chunks(chunks, sdd::TRAJNET_STEP);
    assert_eq!(joined, 1);
    assert_eq!(walks.iter().map(|w| w.id).collect::<Vec<_>>(), vec![1, 2]);
    assert_eq!(walks[0].samples.len(), 40);
    assert_relative_eq!(walks[0].samples[25].p[1], 0.1);
}

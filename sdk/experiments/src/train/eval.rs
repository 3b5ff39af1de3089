//! The held-out evaluation of a trained model: the evaluation windows (with the other agents'
//! true futures when the datasets are present, else from the cache) and the card's record.

use super::{TrainConfig, neighbour_paths, resolve, scene_names};
use anyhow::{Context, bail};
use human2nav_core::flow::CrowdGuidance;
use human2nav_data::cache::TupleCache;
use human2nav_data::tuples::{CompactTuple, Split};
use human2nav_flow::CfmModel;
use human2nav_flow::card::{CrowdProbeInfo, EarlyAde, EvaluationInfo};
use human2nav_flow::eval::{EvalOptions, EvalWindow, counterfactual_probe, crowd_probe, evaluate};
use human2nav_flow::train::Counterfactual;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::Path;

/// The windows of `eval.split` with the other agents' true futures: the split's scenes are
/// rebuilt from the datasets with the data config and the cache's tuple options, and must
/// reproduce the cache's tuples of that split exactly (same count).
fn true_future_windows(
    cfg: &TrainConfig,
    cache: &TupleCache,
    root: &Path,
) -> anyhow::Result<Vec<EvalWindow>> {
    use human2nav_data::config::DataConfig;
    use human2nav_data::pipeline::{Locations, discover, load_source};
    use human2nav_data::resample::resample;
    let path = resolve(root, &cfg.eval.data_config);
    let dcfg = DataConfig::load(&path)?;
    let loc = Locations::resolve(&dcfg, &path);
    if !loc.data_root.is_dir() {
        bail!("datasets not found at {}", loc.data_root.display());
    }
    let m = cache.manifest();
    let (sources, _) = discover(&loc.data_root, &dcfg);
    let split = cfg.eval.split;
    let mut windows = Vec::new();
    for i in m.scenes_in(split) {
        let name = &m.scenes[i as usize].name;
        let src = sources.iter().find(|s| &s.name == name).with_context(|| {
            format!(
                "{} scene {name} not found under {}",
                split.name(),
                loc.data_root.display()
            )
        })?;
        let scene = resample(&load_source(src, &dcfg)?, &dcfg.resample);
        windows.extend(human2nav_flow::eval::scene_windows(
            &scene, i, &m.bev, &m.tuples,
        )?);
    }
    let expected = m.counts.get(&split).copied().unwrap_or(0);
    if windows.len() != expected {
        bail!(
            "rebuilt {} {} windows, the cache has {expected}",
            windows.len(),
            split.name()
        );
    }
    human2nav_flow::eval::subsample(&mut windows, cfg.eval.max_windows, cfg.eval.seed);
    Ok(windows)
}

/// The windows of `eval.split` from the cache alone, see [`cache_windows`].
fn split_windows(cfg: &TrainConfig, cache: &TupleCache) -> anyhow::Result<Vec<EvalWindow>> {
    cache_windows(cache, cfg.eval.split, cfg.eval.max_windows, cfg.eval.seed)
}

/// At most `max` windows of `split` (seeded subsample) from the cache alone: the cache stores
/// the other agents only at the planning instant, so their future positions are extrapolated
/// at constant velocity.
pub fn cache_windows(
    cache: &TupleCache,
    split: Split,
    max: usize,
    seed: u64,
) -> anyhow::Result<Vec<EvalWindow>> {
    let mut compact: Vec<CompactTuple> = cache.load_compact(split)?;
    human2nav_flow::eval::subsample(&mut compact, max, seed);
    let spec = cache.manifest().bev;
    let dt = cache.manifest().dt;
    Ok(compact
        .iter()
        .map(|c| {
            let t = c.to_tuple(&spec);
            let others_cv = neighbour_paths(c, dt);
            let others = others_cv
                .iter()
                .map(|path| path.iter().copied().map(Some).collect())
                .collect();
            EvalWindow::from_tuple(t, others, others_cv)
        })
        .collect())
}

/// Evaluates `model` on the windows of `eval.split`, the test split unless set (with the other
/// agents' true futures when the datasets are present, see `eval.data_config`, else
/// extrapolated from the cache), and returns the card's evaluation record; `root` resolves
/// `eval.data_config`.
pub fn run_evaluation(
    cfg: &TrainConfig,
    cache: &TupleCache,
    model: &CfmModel,
    root: &Path,
) -> anyhow::Result<EvaluationInfo> {
    let (windows, neighbours) = match true_future_windows(cfg, cache, root) {
        Ok(w) => (
            w,
            "other agents' true future positions, from the split's scenes rebuilt with the data \
             config (windows identical to the cache's tuples)",
        ),
        Err(e) => {
            eprintln!(
                "note: true neighbour futures unavailable ({e:#}); extrapolating the cache's"
            );
            (
                split_windows(cfg, cache)?,
                "other agents' future positions extrapolated at constant velocity from their \
                 state at the planning instant (the tuple cache stores neighbours only then)",
            )
        }
    };
    if windows.is_empty() {
        bail!(
            "the {} split of {} is empty",
            cfg.eval.split,
            cache.dir().display()
        );
    }
    let opts = EvalOptions {
        samples: cfg.eval.samples,
        steps: cfg.eval.steps,
        dt: cache.manifest().dt,
        radius: cfg.eval.radius,
        seed: cfg.eval.seed,
        ..EvalOptions::default()
    };
    let bar = ProgressBar::new(windows.len() as u64);
    bar.set_style(ProgressStyle::with_template(
        "evaluating [{wide_bar}] {pos}/{len} windows  ETA {eta}",
    )?);
    let m = evaluate(model, &windows, &opts, |i| bar.set_position(i as u64))?;
    bar.finish_and_clear();
    let mut probes = Vec::with_capacity(cfg.eval.crowd_weights.len());
    for &weight in &cfg.eval.crowd_weights {
        let bar = ProgressBar::new(windows.len() as u64);
        bar.set_style(ProgressStyle::with_template(&format!(
            "probing the crowd's effect, w = {weight} [{{wide_bar}}] {{pos}}/{{len}} windows  ETA {{eta}}"
        ))?);
        let guided = CrowdGuidance::new(model, weight)?;
        let probe = crowd_probe(&guided, &windows, &opts, cfg.eval.contact, |i| {
            bar.set_position(i as u64)
        })?;
        bar.finish_and_clear();
        probes.push((weight, probe));
    }
    if cfg.eval.counterfactual_probe {
        let person = Counterfactual {
            step: cache.manifest().dt,
            ..cfg.train.counterfactual.clone().unwrap_or_default()
        };
        let placing = (&person, cache.manifest().bev);
        for &weight in &cfg.eval.crowd_weights {
            let bar = ProgressBar::new(windows.len() as u64);
            bar.set_style(ProgressStyle::with_template(&format!(
                "probing a counterfactual person, w = {weight} [{{wide_bar}}] {{pos}}/{{len}} windows  ETA {{eta}}"
            ))?);
            let guided = CrowdGuidance::new(model, weight)?;
            let p =
                counterfactual_probe(&guided, &windows, &opts, placing, cfg.eval.contact, |i| {
                    bar.set_position(i as u64)
                })?;
            bar.finish_and_clear();
            eprintln!(
                "{}: counterfactual probe, w = {weight} (a standing person on the straight line, \
                 clear of the recorded future; {} of {} windows): samples meeting the person \
                 {:.3} seen / {:.3} unseen; {:.3} m apart",
                cfg.eval.split,
                p.windows,
                windows.len(),
                p.observed,
                p.hidden,
                p.displacement
            );
        }
    }
    let info = EvaluationInfo {
        protocol: format!(
            "{} windows drawn (seed {}) from the {} split ({}); {} samples per window, {} Euler steps; \
             best-of-{} ADE/FDE against the true 3.2 s future; constant velocity = ego velocity held",
            m.windows,
            cfg.eval.seed,
            cfg.eval.split,
            scene_names(cache, cfg.eval.split),
            opts.samples,
            opts.steps,
            opts.samples
        ),
        windows: m.windows,
        samples_per_window: opts.samples,
        steps: opts.steps,
        min_ade: m.min_ade,
        min_fde: m.min_fde,
        mean_ade: m.mean_ade,
        cv_ade: m.cv_ade,
        cv_fde: m.cv_fde,
        ade_improvement: 1.0 - m.min_ade / m.cv_ade,
        centroid_ade: Some(m.centroid_ade),
        early_ade: Some(EarlyAde {
            seconds: m.early_steps as f64 * opts.dt,
            mean: m.early_mean_ade,
            centroid: m.early_centroid_ade,
            constant_velocity: m.early_cv_ade,
        }),
        proximity_radius: opts.radius,
        proximity_model: m.proximity_model,
        proximity_truth: m.proximity_truth,
        proximity_note: format!(
            "{neighbours}; constant-velocity ego prediction within the radius: {:.4}",
            m.proximity_cv
        ),
        crowd_probe: probes
            .iter()
            .map(|&(weight, p)| CrowdProbeInfo::of(p, weight))
            .collect(),
    };
    eprintln!(
        "{}: best-of-{} ADE {:.3} m FDE {:.3} m | constant velocity ADE {:.3} m FDE {:.3} m | ADE {:.1} % lower | \
         within {} m of another agent: model {:.3}, truth {:.3}, cv {:.3}",
        cfg.eval.split,
        opts.samples,
        m.min_ade,
        m.min_fde,
        m.cv_ade,
        m.cv_fde,
        100.0 * info.ade_improvement,
        opts.radius,
        m.proximity_model,
        m.proximity_truth,
        m.proximity_cv
    );
    eprintln!(
        "{}: one sample ADE {:.3} m | the samples' mean ADE {:.3} m FDE {:.3} m | first {:.1} s: \
         one sample {:.3} m, the samples' mean {:.3} m, constant velocity {:.3} m",
        cfg.eval.split,
        m.mean_ade,
        m.centroid_ade,
        m.centroid_fde,
        m.early_steps as f64 * opts.dt,
        m.early_mean_ade,
        m.early_centroid_ade,
        m.early_cv_ade
    );
    for (weight, probe) in &probes {
        eprintln!(
            "{}: crowd probe, crowd guidance w = {weight} (the same samples with the crowd in the \
             raster and with it emptied; meeting = centres within {} m): recorded futures {:.3} \
             observed / {:.3} hidden (the human {:.3}); constant velocity {:.3} / {:.3} (the \
             human {:.3}); samples {:.3} m apart",
            cfg.eval.split,
            probe.contact,
            probe.observed_recorded,
            probe.hidden_recorded,
            probe.human_recorded,
            probe.observed_cv,
            probe.hidden_cv,
            probe.human_cv,
            probe.displacement
        );
    }
    Ok(info)
}

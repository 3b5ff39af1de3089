//! Selecting a split's suite from the scenes' kept candidates, the mining report
//! ([`InteractionReport`]) and the summary of a suite's classes, densities and goal distances.

use super::{InteractionOptions, InteractionStats};
use crate::error::DataError;
use crate::scenario::{Episode, EpisodeSuite, MiningOptions, ScenarioClass, select_across_scenes};
use crate::tuples::Split;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// What mining the interaction-rich episodes of a split gave
/// ([`crate::pipeline::build_interaction_episodes`]).
#[derive(Clone, Debug)]
pub struct InteractionReport {
    /// The split whose scenes were mined.
    pub split: Split,
    /// The selected episodes.
    pub suite: EpisodeSuite,
    /// Counters per scene mined, in the order mined (scene name order in the pipeline).
    pub scenes: Vec<(String, InteractionStats)>,
    /// The sum over the scenes.
    pub stats: InteractionStats,
    /// Classes, densities and goal distances of the selected suite.
    pub summary: SuiteSummary,
    /// What the user should know (missing datasets, the synthetic fallback, ...).
    pub notes: Vec<String>,
}

/// Selects the suite of a split from every scene's kept candidates (`(scene, candidates,
/// counters)` in scene order): up to `geometry.per_class` per class with
/// [`crate::scenario::select_across_scenes`] seeded by `opts.seed`. A class without any candidate is an
/// error naming the split, the class and the settings most likely responsible; fewer than
/// `per_class` is a note appended to `notes`.
pub fn select_interaction_suite(
    split: Split,
    mined: Vec<(String, Vec<Episode>, InteractionStats)>,
    geometry: &MiningOptions,
    opts: &InteractionOptions,
    mut notes: Vec<String>,
) -> Result<InteractionReport, DataError> {
    let mut all = Vec::new();
    let mut total = InteractionStats::default();
    let mut scenes = Vec::with_capacity(mined.len());
    for (name, eps, st) in mined {
        all.extend(eps);
        total.add(&st);
        scenes.push((name, st));
    }
    for c in ScenarioClass::ALL {
        let kept = total.kept_of(c);
        if kept == 0 {
            return Err(DataError::option(
                "interaction.reference_speeds",
                format!(
                    "{split} split: no interactive {c} episode ({} {c} candidates classified, \
                     none met someone at every reference speed; {} candidates tried); relax \
                     interaction.reference_speeds {:?} m/s or interaction.min_time_shift {} s, \
                     or raise interaction.shifts_per_path {}",
                    total.classified_of(c),
                    total.candidates,
                    opts.reference_speeds,
                    opts.min_time_shift,
                    opts.shifts_per_path
                ),
            ));
        }
        if kept < geometry.per_class {
            notes.push(format!(
                "{split}: only {kept} interactive {c} candidates for episodes.per_class = {}",
                geometry.per_class
            ));
        }
    }
    let names: Vec<&str> = scenes.iter().map(|(n, _)| n.as_str()).collect();
    let episodes = select_across_scenes(all, geometry.per_class, opts.seed);
    let suite = EpisodeSuite::new(
        format!("interaction ({split}): {}", names.join(", ")),
        episodes,
    );
    Ok(InteractionReport {
        split,
        summary: summarize(&suite.episodes),
        suite,
        scenes,
        stats: total,
        notes,
    })
}

impl InteractionReport {
    /// The report as Markdown: the criterion's pass counts per scene and class, the rejections,
    /// the selected suite's classes, densities and goal distances, and the notes.
    pub fn markdown(&self, opts: &InteractionOptions) -> String {
        use std::fmt::Write as _;
        let mut md = String::new();
        let classes = ScenarioClass::ALL;
        let _ = writeln!(
            md,
            "# Interaction-rich episodes, {} split\n\n{}\n\nA candidate is a pedestrian's \
             window (either direction) with the scene's crowd from at least {} s away \
             ({} crowd starts drawn per path); it is interactive when a straight-driving \
             reference disc (r {} m, {} m/s², from rest) meets a pedestrian whose track is at \
             least {} s old at every speed of {:?} m/s. `kept`: at most one per window, \
             direction and class.\n",
            self.split,
            self.suite.source,
            opts.min_time_shift,
            opts.shifts_per_path,
            opts.reference_radius,
            opts.reference_accel,
            opts.min_track_age,
            opts.reference_speeds
        );
        let _ = write!(md, "| scene | windows | candidates | classified |");
        for c in classes {
            let _ = write!(md, " {c} interactive / kept / selected |");
        }
        let _ = writeln!(md, "\n|---|---|---|---|{}", "---|".repeat(classes.len()));
        let selected = |scene: Option<&str>, c: ScenarioClass| {
            self.suite
                .episodes
                .iter()
                .filter(|e| e.scenario == c && scene.is_none_or(|s| e.scene == s))
                .count()
        };
        let rows = self
            .scenes
            .iter()
            .map(|(n, st)| (n.as_str(), Some(n.as_str()), st))
            .chain(std::iter::once(("all", None, &self.stats)));
        for (name, scene, st) in rows {
            let classified: usize = classes.iter().map(|&c| st.classified_of(c)).sum();
            let _ = write!(
                md,
                "| {name} | {} | {} | {classified} |",
                st.windows, st.candidates
            );
            for c in classes {
                let _ = write!(
                    md,
                    " {} / {} / {} |",
                    st.interactive.get(&c).copied().unwrap_or(0),
                    st.kept_of(c),
                    selected(scene, c)
                );
            }
            let _ = writeln!(md);
        }
        let st = &self.stats;
        let _ = writeln!(
            md,
            "\nRejected: {} outside the recording, {} start blocked, {} density out of range \
             (nobody within the density radius, mostly), {} unclassified, {} not interactive; {} \
             path directions had no crowd window far enough away.\n",
            st.outside_recording,
            st.start_blocked,
            st.density_out_of_range,
            st.unclassified,
            st.not_interactive.values().sum::<usize>(),
            st.no_crowd_window
        );
        if !opts.exclude_episodes.is_empty() {
            let files: Vec<String> = opts
                .exclude_episodes
                .iter()
                .map(|p| format!("`{}`", p.display()))
                .collect();
            let _ = writeln!(
                md,
                "Withheld: {} kept candidates ({}) are episodes of {} \
                 (`interaction.exclude_episodes`) and were not selected; `kept` counts the \
                 others.\n",
                st.withheld.values().sum::<usize>(),
                classes
                    .iter()
                    .map(|c| format!("{c} {}", st.withheld.get(c).copied().unwrap_or(0)))
                    .collect::<Vec<_>>()
                    .join(", "),
                files.join(", ")
            );
        }
        let _ = writeln!(
            md,
            "Selected suite (density = people within the density radius of the \
             reference during its slowest drive):\n\n```\n{}\n```",
            self.summary
        );
        for n in &self.notes {
            let _ = writeln!(md, "\nNote: {n}");
        }
        md
    }
}

/// Upper bounds of the density bins of [`SuiteSummary`]: 1–2, 3–5, 6–10, 11–20, 21–40, 41+
/// (the first bin also holds density 0, possible only with `min_density = 0`).
pub const DENSITY_BINS: [(usize, Option<usize>); 6] = [
    (1, Some(2)),
    (3, Some(5)),
    (6, Some(10)),
    (11, Some(20)),
    (21, Some(40)),
    (41, None),
];

/// Density histogram over [`DENSITY_BINS`], with the largest density.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct DensityHistogram {
    /// Episodes per bin of [`DENSITY_BINS`].
    pub bins: [usize; 6],
    /// The largest density counted.
    pub max: usize,
}

impl DensityHistogram {
    /// Counts one episode's density.
    pub fn add(&mut self, density: usize) {
        let k = DENSITY_BINS
            .iter()
            .position(|(_, hi)| hi.is_none_or(|h| density <= h))
            .unwrap_or(DENSITY_BINS.len() - 1);
        self.bins[k] += 1;
        self.max = self.max.max(density);
    }
}

/// What a selected suite looks like: episodes, densities and goal distances per class.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SuiteSummary {
    /// Episodes per class.
    pub per_class: BTreeMap<ScenarioClass, usize>,
    /// Densities of all episodes.
    pub density: DensityHistogram,
    /// Densities per class.
    pub density_per_class: BTreeMap<ScenarioClass, DensityHistogram>,
    /// Goal distance `[min, median, mean, max]`, metres (zeros for an empty suite).
    pub goal_distance: [f64; 4],
}

/// Summarises a list of episodes.
pub fn summarize(episodes: &[Episode]) -> SuiteSummary {
    let mut s = SuiteSummary::default();
    for c in ScenarioClass::ALL {
        s.per_class.insert(c, 0);
        s.density_per_class.insert(c, DensityHistogram::default());
    }
    for e in episodes {
        *s.per_class.entry(e.scenario).or_default() += 1;
        s.density.add(e.density);
        s.density_per_class
            .entry(e.scenario)
            .or_default()
            .add(e.density);
    }
    let mut d: Vec<f64> = episodes.iter().map(Episode::goal_distance).collect();
    if !d.is_empty() {
        d.sort_by(f64::total_cmp);
        let n = d.len();
        let median = if n % 2 == 1 {
            d[n / 2]
        } else {
            0.5 * (d[n / 2 - 1] + d[n / 2])
        };
        s.goal_distance = [d[0], median, d.iter().sum::<f64>() / n as f64, d[n - 1]];
    }
    s
}

impl std::fmt::Display for SuiteSummary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{:<20} {:>5}", "class", "n")?;
        for (lo, hi) in DENSITY_BINS {
            let label = match hi {
                Some(h) => format!("{lo}-{h}"),
                None => format!("{lo}+"),
            };
            write!(f, " {label:>6}")?;
        }
        writeln!(f, " {:>5}", "max")?;
        let row = |f: &mut std::fmt::Formatter<'_>, name: &str, n: usize, h: &DensityHistogram| {
            write!(f, "{name:<20} {n:>5}")?;
            for b in h.bins {
                write!(f, " {b:>6}")?;
            }
            writeln!(f, " {:>5}", h.max)
        };
        for (c, h) in &self.density_per_class {
            row(f, c.name(), self.per_class.get(c).copied().unwrap_or(0), h)?;
        }
        let total = self.per_class.values().sum();
        row(f, "all", total, &self.density)?;
        let [lo, med, mean, hi] = self.goal_distance;
        write!(
            f,
            "goal distance [m]: min {lo:.2}, median {med:.2}, mean {mean:.2}, max {hi:.2}"
        )
    }
}

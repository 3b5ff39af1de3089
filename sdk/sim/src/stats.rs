//! The statistics of the report: paired comparisons of two methods on the same runs (exact
//! McNemar test, paired bootstrap interval of the SR difference), Wilson score intervals of a
//! success rate, the normal interval of a mean, crowd-density bins and the composition of a
//! suite. Pure functions; every random draw comes from a fixed seed, so the report is
//! deterministic.

use crate::bench::ResultRow;
use crate::episode::{Episode, ScenarioClass};
use std::collections::HashMap;

/// The standard normal quantile of a two-sided 95 % interval.
pub const Z95: f64 = 1.959_963_984_540_054;

/// Resamples of the paired bootstrap in the report.
pub const BOOTSTRAP_RESAMPLES: usize = 2000;

/// Seed of the paired bootstrap in the report.
pub const BOOTSTRAP_SEED: u64 = 0x5eed_b007_57a9_0001;

/// `P(X ≤ k)` for `X ~ Binomial(n, 1/2)`, summed in log space (no overflow for any `n`).
pub fn binomial_half_cdf(n: usize, k: usize) -> f64 {
    if k >= n {
        return 1.0;
    }
    let ln_half_n = -(n as f64) * std::f64::consts::LN_2;
    // ln C(n, i), built up term by term.
    let mut ln_choose = 0.0;
    let mut total = 0.0;
    for i in 0..=k {
        if i > 0 {
            ln_choose += ((n - i + 1) as f64).ln() - (i as f64).ln();
        }
        total += (ln_choose + ln_half_n).exp();
    }
    total.min(1.0)
}

/// The exact two-sided McNemar test of `b` pairs where only the first method succeeded
/// against `c` pairs where only the second did: under the null hypothesis (both methods
/// equally good) each of the `b + c` discordant pairs goes either way with probability 1/2, so
/// `p = min(1, 2·P(X ≤ min(b, c)))` with `X ~ Binomial(b + c, 1/2)`; `p = 1` without a
/// discordant pair.
pub fn mcnemar_exact(b: usize, c: usize) -> f64 {
    if b + c == 0 {
        return 1.0;
    }
    (2.0 * binomial_half_cdf(b + c, b.min(c))).min(1.0)
}

/// The Wilson score interval of a success rate of `successes` out of `n` at normal quantile
/// `z` (`None` when `n = 0`). Unlike `SR ± z·SE` it stays inside `[0, 1]` and is not empty at
/// SR = 0 or 1.
pub fn wilson_interval(successes: usize, n: usize, z: f64) -> Option<(f64, f64)> {
    if n == 0 {
        return None;
    }
    let nf = n as f64;
    let p = successes.min(n) as f64 / nf;
    let z2 = z * z;
    let denom = 1.0 + z2 / nf;
    let centre = (p + z2 / (2.0 * nf)) / denom;
    let half = z / denom * (p * (1.0 - p) / nf + z2 / (4.0 * nf * nf)).sqrt();
    Some(((centre - half).max(0.0), (centre + half).min(1.0)))
}

/// The mean of `values` and `z` standard errors of the mean (sample standard deviation,
/// `n − 1`): `(mean, z·s/√n)`; the half-width is 0 for a single value, `None` for none.
pub fn mean_with_error(values: &[f64], z: f64) -> Option<(f64, f64)> {
    let n = values.len();
    if n == 0 {
        return None;
    }
    let mean = values.iter().sum::<f64>() / n as f64;
    if n == 1 {
        return Some((mean, 0.0));
    }
    let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    Some((mean, z * (var / n as f64).sqrt()))
}

/// SplitMix64: a small, fast generator with a fixed, platform-independent sequence.
#[derive(Clone, Debug)]
struct SplitMix64(u64);

impl SplitMix64 {
    fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n > 0`), by the multiply-shift reduction.
    fn below(&mut self, n: usize) -> usize {
        ((u128::from(self.next_u64()) * n as u128) >> 64) as usize
    }
}

/// The `q` quantile of sorted values, linearly interpolated between order statistics (the
/// usual "type 7" definition).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let h = (sorted.len() - 1) as f64 * q.clamp(0.0, 1.0);
    let lo = h.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    sorted[lo] + (h - lo as f64) * (sorted[hi] - sorted[lo])
}

/// The paired percentile bootstrap interval (coverage `level`, e.g. 0.95) of
/// `SR(first) − SR(second)` over `pairs` of `(first succeeded, second succeeded)`: the pairs
/// are resampled with replacement `resamples` times from `seed`, the difference is computed on
/// each resample, and the interval runs between the `(1 − level)/2` and `(1 + level)/2`
/// quantiles. The result depends on the pairs as a multiset (not on their order). `None`
/// without pairs or resamples.
pub fn paired_bootstrap_ci(
    pairs: &[(bool, bool)],
    resamples: usize,
    level: f64,
    seed: u64,
) -> Option<(f64, f64)> {
    let n = pairs.len();
    if n == 0 || resamples == 0 {
        return None;
    }
    // Each pair contributes −1, 0 or +1; sorted, a drawn index says which by its range.
    let minus = pairs.iter().filter(|(a, b)| !a && *b).count();
    let plus = pairs.iter().filter(|(a, b)| *a && !b).count();
    let plus_from = n - plus;
    let mut rng = SplitMix64(seed);
    let mut diffs: Vec<f64> = (0..resamples)
        .map(|_| {
            let mut sum = 0i64;
            for _ in 0..n {
                let i = rng.below(n);
                if i < minus {
                    sum -= 1;
                } else if i >= plus_from {
                    sum += 1;
                }
            }
            sum as f64 / n as f64
        })
        .collect();
    diffs.sort_by(f64::total_cmp);
    let tail = 0.5 * (1.0 - level.clamp(0.0, 1.0));
    Some((quantile(&diffs, tail), quantile(&diffs, 1.0 - tail)))
}

/// A paired comparison of a reference method against another on the same runs.
#[derive(Clone, Debug, PartialEq)]
pub struct PairedComparison {
    /// Pairs: runs of both methods on the same (episode, robot).
    pub n: usize,
    /// SR of the reference over the pairs.
    pub sr_reference: f64,
    /// SR of the other method over the pairs.
    pub sr_other: f64,
    /// `sr_reference − sr_other` (`(b − c)/n`).
    pub difference: f64,
    /// Pairs only the reference succeeded on.
    pub b: usize,
    /// Pairs only the other method succeeded on.
    pub c: usize,
    /// Exact two-sided McNemar p-value ([`mcnemar_exact`]).
    pub p_value: f64,
    /// 95 % paired bootstrap interval of `difference` ([`paired_bootstrap_ci`] with
    /// [`BOOTSTRAP_RESAMPLES`] and [`BOOTSTRAP_SEED`]).
    pub ci: (f64, f64),
}

impl PairedComparison {
    /// The comparison over `pairs` of `(reference succeeded, other succeeded)`; `None` without
    /// pairs.
    pub fn of(pairs: &[(bool, bool)]) -> Option<Self> {
        let n = pairs.len();
        let ci = paired_bootstrap_ci(pairs, BOOTSTRAP_RESAMPLES, 0.95, BOOTSTRAP_SEED)?;
        let count = |f: fn(&(bool, bool)) -> bool| pairs.iter().filter(|p| f(p)).count();
        let b = count(|p| p.0 && !p.1);
        let c = count(|p| !p.0 && p.1);
        let sr_reference = count(|p| p.0) as f64 / n as f64;
        let sr_other = count(|p| p.1) as f64 / n as f64;
        Some(Self {
            n,
            sr_reference,
            sr_other,
            difference: (b as f64 - c as f64) / n as f64,
            b,
            c,
            p_value: mcnemar_exact(b, c),
            ci,
        })
    }
}

/// The `(reference succeeded, other succeeded)` pairs of `rows` (already restricted to one
/// suite and whatever group is wanted): one per (episode, robot) that both methods ran, in the
/// order of the reference's rows.
pub fn success_pairs<'a>(
    rows: impl IntoIterator<Item = &'a ResultRow>,
    reference: &str,
    other: &str,
) -> Vec<(bool, bool)> {
    let mut reference_rows: Vec<&ResultRow> = Vec::new();
    let mut others: HashMap<(&str, &str), bool> = HashMap::new();
    for r in rows {
        if r.method == reference {
            reference_rows.push(r);
        } else if r.method == other {
            others.insert((&r.episode, &r.robot), r.metrics.success);
        }
    }
    reference_rows
        .into_iter()
        .filter_map(|r| {
            others
                .get(&(r.episode.as_str(), r.robot.as_str()))
                .map(|&o| (r.metrics.success, o))
        })
        .collect()
}

/// A range of crowd densities (the episode's relevant pedestrians), both ends included.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DensityBin {
    /// Lowest density in the bin.
    pub lo: usize,
    /// `None`: no upper end.
    pub hi: Option<usize>,
}

impl DensityBin {
    /// `0`, `1–2`, …, `41+`.
    pub fn label(&self) -> String {
        match self.hi {
            Some(hi) if hi == self.lo => self.lo.to_string(),
            Some(hi) => format!("{}–{hi}", self.lo),
            None => format!("{}+", self.lo),
        }
    }

    /// True when `density` falls in the bin.
    pub fn contains(&self, density: usize) -> bool {
        density >= self.lo && self.hi.is_none_or(|hi| density <= hi)
    }
}

/// The density bins of the report, in order (the first holds the empty-world episodes).
pub const DENSITY_BINS: [DensityBin; 7] = [
    DensityBin { lo: 0, hi: Some(0) },
    DensityBin { lo: 1, hi: Some(2) },
    DensityBin { lo: 3, hi: Some(5) },
    DensityBin {
        lo: 6,
        hi: Some(10),
    },
    DensityBin {
        lo: 11,
        hi: Some(20),
    },
    DensityBin {
        lo: 21,
        hi: Some(40),
    },
    DensityBin { lo: 41, hi: None },
];

/// The index in [`DENSITY_BINS`] of the bin holding `density`.
pub fn density_bin(density: usize) -> usize {
    DENSITY_BINS
        .iter()
        .position(|b| b.contains(density))
        .unwrap_or(DENSITY_BINS.len() - 1)
}

/// The indices of the [`DENSITY_BINS`] that hold at least one of `densities`, in order.
pub fn occupied_bins(densities: impl IntoIterator<Item = usize>) -> Vec<usize> {
    let mut used = [false; DENSITY_BINS.len()];
    for d in densities {
        used[density_bin(d)] = true;
    }
    (0..DENSITY_BINS.len()).filter(|&i| used[i]).collect()
}

/// The median of `values` (the mean of the middle two for an even count; `None` for none).
pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    Some(if v.len() % 2 == 0 {
        0.5 * (v[m - 1] + v[m])
    } else {
        v[m]
    })
}

/// The episodes of one scenario class (or of all) in a suite.
#[derive(Clone, Debug, PartialEq)]
pub struct ClassComposition {
    /// `None`: every class.
    pub class: Option<ScenarioClass>,
    /// Episodes of the class.
    pub episodes: usize,
    /// Episodes per [`DENSITY_BINS`] entry.
    pub density_histogram: [usize; DENSITY_BINS.len()],
    /// Start-to-goal straight-line distance (m): `(min, median, max)`, `None` without episodes.
    pub goal_distance: Option<(f64, f64, f64)>,
}

impl ClassComposition {
    /// The composition of the episodes of `class` (`None`: all) among `episodes`.
    pub fn of(episodes: &[Episode], class: Option<ScenarioClass>) -> Self {
        let picked: Vec<&Episode> = episodes
            .iter()
            .filter(|e| class.is_none_or(|c| e.scenario == c))
            .collect();
        let mut density_histogram = [0; DENSITY_BINS.len()];
        for e in &picked {
            density_histogram[density_bin(e.density)] += 1;
        }
        let distances: Vec<f64> = picked.iter().map(|e| e.goal_distance()).collect();
        let goal_distance = median(&distances).map(|m| {
            let lo = distances.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = distances.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (lo, m, hi)
        });
        Self {
            class,
            episodes: picked.len(),
            density_histogram,
            goal_distance,
        }
    }
}

/// What a suite holds: one [`ClassComposition`] per scenario class, then one over all.
#[derive(Clone, Debug, PartialEq)]
pub struct SuiteComposition {
    /// The suite's name.
    pub suite: String,
    /// One entry per scenario class, then one over all classes.
    pub classes: Vec<ClassComposition>,
}

impl SuiteComposition {
    /// The composition of the suite `suite` holding `episodes`.
    pub fn of(suite: &str, episodes: &[Episode]) -> Self {
        Self {
            suite: suite.to_string(),
            classes: ScenarioClass::ALL
                .into_iter()
                .map(Some)
                .chain([None])
                .map(|c| ClassComposition::of(episodes, c))
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use approx::assert_relative_eq;

    #[test]
    fn binomial_tails_by_hand() {
        // n = 12: P(X ≤ 2) = (1 + 12 + 66) / 4096.
        assert_relative_eq!(binomial_half_cdf(12, 2), 79.0 / 4096.0, epsilon = 1e-15);
        assert_relative_eq!(binomial_half_cdf(1, 0), 0.5, epsilon = 1e-15);
        assert_eq!(binomial_half_cdf(5, 5), 1.0);
        // Symmetry: P(X ≤ k) + P(X ≤ n − k − 1) = 1.
        assert_relative_eq!(
            binomial_half_cdf(41, 13) + binomial_half_cdf(41, 27),
            1.0,
            epsilon = 1e-12
        );
        // Large n stays finite: P(X ≤ 500) of n = 1000 is a little above 1/2.
        let p = binomial_half_cdf(1000, 500);
        assert!(p > 0.5 && p < 0.52, "{p}");
    }

    #[test]
    fn mcnemar_against_hand_computed_tails() {
        // b = 10, c = 2: 2 · 79/4096.
        assert_relative_eq!(mcnemar_exact(10, 2), 0.038_574_218_75, epsilon = 1e-12);
        assert_relative_eq!(mcnemar_exact(2, 10), 0.038_574_218_75, epsilon = 1e-12);
        // b = 5, c = 0: 2 · 1/32.
        assert_relative_eq!(mcnemar_exact(5, 0), 0.0625, epsilon = 1e-15);
        assert_relative_eq!(
            mcnemar_exact(30, 12),
            0.007_915_897_334_896_727,
            epsilon = 1e-12
        );
        assert_relative_eq!(
            mcnemar_exact(120, 80),
            0.005_685_155_996_750_305_5,
            epsilon = 1e-12
        );
        assert_eq!(mcnemar_exact(7, 7), 1.0);
        assert_eq!(mcnemar_exact(0, 1), 1.0);
        assert_eq!(mcnemar_exact(0, 0), 1.0);
    }

    #[test]
    fn wilson_intervals_by_hand() {
        let (lo, hi) = wilson_interval(8, 10, Z95).unwrap();
        assert_relative_eq!(lo, 0.490_162_471_536_641_8, epsilon = 1e-12);
        assert_relative_eq!(hi, 0.943_317_848_545_624_8, epsilon = 1e-12);
        let (lo, hi) = wilson_interval(0, 10, Z95).unwrap();
        assert_eq!(lo, 0.0);
        assert_relative_eq!(hi, 0.277_532_799_862_889_2, epsilon = 1e-12);
        let (lo, hi) = wilson_interval(10, 10, Z95).unwrap();
        assert_relative_eq!(lo, 0.722_467_200_137_110_7, epsilon = 1e-12);
        assert_relative_eq!(hi, 1.0, epsilon = 1e-12);
        assert!(wilson_interval(0, 0, Z95).is_none());
    }

    #[test]
    fn mean_error_is_z_standard_errors() {
        // Values 1, 2, 3, 4: mean 2.5, s² = 5/3, SE = sqrt(5/12).
        let (m, e) = mean_with_error(&[1.0, 2.0, 3.0, 4.0], 2.0).unwrap();
        assert_relative_eq!(m, 2.5);
        assert_relative_eq!(e, 2.0 * (5.0f64 / 12.0).sqrt(), epsilon = 1e-12);
        assert_eq!(mean_with_error(&[0.7], Z95), Some((0.7, 0.0)));
        assert!(mean_with_error(&[], Z95).is_none());
    }

    fn pairs(both: usize, b: usize, c: usize, neither: usize) -> Vec<(bool, bool)> {
        std::iter::repeat_n((true, true), both)
            .chain(std::iter::repeat_n((true, false), b))
            .chain(std::iter::repeat_n((false, true), c))
            .chain(std::iter::repeat_n((false, false), neither))
            .collect()
    }

    #[test]
    fn bootstrap_contains_the_difference_and_is_deterministic() {
        let p = pairs(60, 25, 10, 5);
        let (lo, hi) = paired_bootstrap_ci(&p, 2000, 0.95, 1).unwrap();
        let d = 15.0 / 100.0;
        assert!(lo < d && d < hi, "{lo} {hi}");
        // Roughly ±1.96 · SE of the paired difference: SE = sqrt((b + c)/n − d²)/√n ≈ 0.055.
        assert!((hi - lo) > 0.15 && (hi - lo) < 0.28, "{lo} {hi}");
        assert_eq!(paired_bootstrap_ci(&p, 2000, 0.95, 1), Some((lo, hi)));
        // The order of the pairs does not matter.
        let mut q = p.clone();
        q.reverse();
        assert_eq!(paired_bootstrap_ci(&q, 2000, 0.95, 1), Some((lo, hi)));
        // Another seed moves the ends a little.
        let (lo2, hi2) = paired_bootstrap_ci(&p, 2000, 0.95, 2).unwrap();
        assert!((lo2 - lo).abs() < 0.03 && (hi2 - hi).abs() < 0.03);
        assert!(paired_bootstrap_ci(&[], 2000, 0.95, 1).is_none());
    }

    #[test]
    fn bootstrap_is_degenerate_on_identical_pairs() {
        for p in [pairs(0, 0, 0, 40), pairs(40, 0, 0, 0), pairs(0, 40, 0, 0)] {
            let d = PairedComparison::of(&p).unwrap();
            assert_eq!(d.ci.0, d.ci.1, "{d:?}");
            assert_eq!(d.ci.0, d.difference, "{d:?}");
        }
    }

    #[test]
    fn paired_comparison_counts() {
        let d = PairedComparison::of(&pairs(3, 10, 2, 5)).unwrap();
        assert_eq!((d.n, d.b, d.c), (20, 10, 2));
        assert_relative_eq!(d.sr_reference, 13.0 / 20.0);
        assert_relative_eq!(d.sr_other, 5.0 / 20.0);
        assert_relative_eq!(d.difference, 0.4);
        assert_relative_eq!(d.p_value, 0.038_574_218_75, epsilon = 1e-12);
        assert!(d.ci.0 < 0.4 && 0.4 < d.ci.1);
        assert!(PairedComparison::of(&[]).is_none());
    }

    #[test]
    fn density_bins() {
        let labels: Vec<String> = DENSITY_BINS.iter().map(DensityBin::label).collect();
        assert_eq!(labels, ["0", "1–2", "3–5", "6–10", "11–20", "21–40", "41+"]);
        for (d, bin) in [
            (0, 0),
            (1, 1),
            (2, 1),
            (3, 2),
            (10, 3),
            (11, 4),
            (40, 5),
            (41, 6),
        ] {
            assert_eq!(density_bin(d), bin, "density {d}");
        }
        assert_eq!(density_bin(10_000), 6);
        assert_eq!(occupied_bins([4, 1, 3, 57]), vec![1, 2, 6]);
    }

    fn episode(id: &str, scenario: ScenarioClass, goal: [f64; 2], density: usize) -> Episode {
        Episode {
            id: id.into(),
            scene: "test".into(),
            source: "test".into(),
            scenario,
            dt: 0.1,
            start: human2nav_core::Pose2::new(1.0, 1.0, 0.0),
            goal,
            time_budget: 12.5,
            agents: Vec::new(),
            density,
            obstacles: Vec::new(),
            human_path: Vec::new(),
        }
    }

    #[test]
    fn suite_composition_per_class_and_overall() {
        let eps = [
            episode("a", ScenarioClass::CoFlow, [4.0, 5.0], 1),
            episode("b", ScenarioClass::CoFlow, [7.0, 1.0], 4),
            episode("c", ScenarioClass::CoFlow, [1.0, 6.0], 50),
            episode("d", ScenarioClass::CounterFlow, [1.0, 9.0], 12),
        ];
        let s = SuiteComposition::of("s", &eps);
        assert_eq!(s.classes.len(), 5);
        let co = &s.classes[0];
        assert_eq!(co.class, Some(ScenarioClass::CoFlow));
        assert_eq!(co.episodes, 3);
        assert_eq!(co.density_histogram, [0, 1, 1, 0, 0, 0, 1]);
        // Goal distances 5, 6 and 5.
        assert_eq!(co.goal_distance, Some((5.0, 5.0, 6.0)));
        let cross = &s.classes[1];
        assert_eq!((cross.episodes, cross.goal_distance), (0, None));
        let all = &s.classes[4];
        assert_eq!(all.class, None);
        assert_eq!(all.episodes, 4);
        assert_eq!(all.density_histogram, [0, 1, 1, 0, 1, 0, 1]);
        assert_eq!(all.goal_distance, Some((5.0, 5.5, 8.0)));
    }

    #[test]
    fn medians() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
        assert_eq!(median(&[]), None);
    }
}

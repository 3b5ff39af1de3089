//! Selecting up to `per_class` episodes per class from the mined candidates, spread over
//! densities (and, across scenes, over the scenes).

use super::{Episode, ScenarioClass};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use std::collections::BTreeMap;

/// Picks up to `per_class` episodes of each class, spreading them over densities: classes are
/// filled round-robin over density values, each density's candidates in a seeded shuffled
/// order. The result is sorted by class, then id. Deterministic for a given input order.
pub fn select(candidates: Vec<Episode>, per_class: usize, seed: u64) -> Vec<Episode> {
    select_with(candidates, per_class, seed, false)
}

/// Like [`select`], but each density's next episode comes from the scene with the fewest
/// episodes in the class so far (the first in the shuffled order among ties), so that the
/// scenes with the most candidates do not fill the common densities.
pub fn select_across_scenes(candidates: Vec<Episode>, per_class: usize, seed: u64) -> Vec<Episode> {
    select_with(candidates, per_class, seed, true)
}

fn select_with(
    candidates: Vec<Episode>,
    per_class: usize,
    seed: u64,
    spread_scenes: bool,
) -> Vec<Episode> {
    let mut out = Vec::new();
    for class in ScenarioClass::ALL {
        let mut by_density: BTreeMap<usize, Vec<Episode>> = BTreeMap::new();
        for e in candidates.iter().filter(|e| e.scenario == class) {
            by_density.entry(e.density).or_default().push(e.clone());
        }
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
            seed ^ (class.index() as u64).wrapping_mul(0x9E37_79B9),
        );
        for v in by_density.values_mut() {
            v.shuffle(&mut rng);
        }
        let mut per_scene: BTreeMap<String, usize> = BTreeMap::new();
        let mut picked = Vec::new();
        while picked.len() < per_class && by_density.values().any(|v| !v.is_empty()) {
            for v in by_density.values_mut() {
                if picked.len() >= per_class {
                    break;
                }
                let used = |e: &Episode| {
                    if spread_scenes {
                        per_scene.get(&e.scene).copied().unwrap_or(0)
                    } else {
                        0
                    }
                };
                // The first of the least used scenes, in the shuffled order.
                let Some(i) = (0..v.len()).min_by_key(|&i| used(&v[i])) else {
                    continue;
                };
                let e = v.remove(i);
                *per_scene.entry(e.scene.clone()).or_default() += 1;
                picked.push(e);
            }
        }
        picked.sort_by(|a, b| a.id.cmp(&b.id));
        out.extend(picked);
    }
    out
}

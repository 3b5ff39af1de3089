//! The versioned binary tuple cache: `manifest.json` plus one `<split>.bin` per split.
//!
//! `<split>.bin` (little-endian):
//! * header (24 bytes): magic `H2NTUPL1`, format version `u32`, horizon `u32`, count `u64`;
//! * per tuple: `scene u16`, `class u8` (index into [`ScenarioClass::ALL`], 255 = none),
//!   `0u8`, `n_agents u16`, `0u16`, then `f32`s: goal (2), velocity (2), future
//!   (`horizon × 3`), agents (`n_agents × 5`: x, y, v_x, v_y, radius in the ego frame).
//!
//! Dense rasters are drawn at load time ([`CompactTuple::to_tuple`]); a dense tuple costs
//! `3·H·W·4` bytes (12 KiB at 32 × 32), the stored one about 0.5 KiB.

use crate::error::DataError;
use crate::input_limits::{MAX_CACHE_FILE_BYTES, MAX_MANIFEST_BYTES};
use crate::scenario::ScenarioClass;
use crate::tuples::{CompactTuple, MAX_HORIZON, Split, TrainingTuple, TupleOptions, TupleStats};
use human2nav_core::bev::BevSpec;
use human2nav_core::input::{read_user_bytes, read_user_file};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Version of the cache format (manifest and binary files).
pub const CACHE_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"H2NTUPL1";
const HEADER: usize = 24;

/// One scene of the cache.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SceneInfo {
    /// `dataset/scene`.
    pub name: String,
    /// Dataset name (`eth`, `ucy`, `sdd`, `synthetic`).
    pub dataset: String,
    /// Loader format the scene came from.
    pub format: String,
    /// The split the scene belongs to.
    pub split: Split,
    /// Recorded time covered by the scene's tracks, seconds.
    pub duration: f64,
    /// Tracks on the 0.1 s grid.
    pub tracks: usize,
    /// Training tuples made from the scene.
    pub tuples: usize,
    /// Median speed of the samples faster than 0.2 m/s, m/s.
    pub median_speed: Option<f64>,
    /// Rows and tracks skipped on the way (loader and resampler counters).
    pub skipped: BTreeMap<String, usize>,
}

/// Everything needed to interpret the binary files.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// Cache format version ([`CACHE_VERSION`] when written).
    pub version: u32,
    /// Where the data came from (`real` or `synthetic`).
    pub source: String,
    /// The raster every tuple's BEV was drawn with.
    pub bev: BevSpec,
    /// Future poses per tuple.
    pub horizon: usize,
    /// Step between poses, seconds.
    pub dt: f64,
    /// The options the tuples were made with.
    pub tuples: TupleOptions,
    /// Every scene of the cache, in the index order tuples refer to.
    pub scenes: Vec<SceneInfo>,
    /// Tuples per split.
    pub counts: BTreeMap<Split, usize>,
    /// What tuple making skipped, over all scenes.
    pub stats: TupleStats,
    /// Size in bytes of each split's file as written with this manifest; a file of another
    /// size belongs to another (or an interrupted) build. Empty in caches written before the
    /// sizes were recorded.
    #[serde(default)]
    pub file_bytes: BTreeMap<Split, u64>,
}

impl Manifest {
    /// Indices of the scenes of `split`.
    pub fn scenes_in(&self, split: Split) -> Vec<u16> {
        self.scenes
            .iter()
            .enumerate()
            .filter(|(_, s)| s.split == split)
            .map(|(i, _)| i as u16)
            .collect()
    }
}

/// A tuple cache on disk.
#[derive(Clone, Debug)]
pub struct TupleCache {
    dir: PathBuf,
    manifest: Manifest,
}

fn file_of(dir: &Path, split: Split) -> PathBuf {
    dir.join(format!("{}.bin", split.name()))
}

fn put_f32s(w: &mut Vec<u8>, v: &[f32]) {
    for x in v {
        w.extend_from_slice(&x.to_le_bytes());
    }
}

fn encode(t: &CompactTuple, buf: &mut Vec<u8>) {
    buf.extend_from_slice(&t.scene.to_le_bytes());
    buf.push(t.class.map(|c| c.index() as u8).unwrap_or(255));
    buf.push(0);
    buf.extend_from_slice(&(t.agents.len().min(u16::MAX as usize) as u16).to_le_bytes());
    buf.extend_from_slice(&0u16.to_le_bytes());
    put_f32s(buf, &t.goal);
    put_f32s(buf, &t.velocity);
    for p in &t.future {
        put_f32s(buf, p);
    }
    for a in t.agents.iter().take(u16::MAX as usize) {
        put_f32s(buf, a);
    }
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    path: &'a Path,
}

impl Reader<'_> {
    fn take(&mut self, n: usize) -> Result<&[u8], DataError> {
        let end = self
            .at
            .checked_add(n)
            .filter(|&e| e <= self.b.len())
            .ok_or_else(|| DataError::Cache {
                path: self.path.to_path_buf(),
                message: format!("truncated at byte {}", self.at),
            })?;
        let s = &self.b[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn u16(&mut self) -> Result<u16, DataError> {
        let s = self.take(2)?;
        Ok(u16::from_le_bytes([s[0], s[1]]))
    }
    fn f32(&mut self) -> Result<f32, DataError> {
        let s = self.take(4)?;
        let v = f32::from_le_bytes([s[0], s[1], s[2], s[3]]);
        if !v.is_finite() {
            return Err(DataError::Cache {
                path: self.path.to_path_buf(),
                message: format!("non-finite value at byte {}", self.at - 4),
            });
        }
        Ok(v)
    }
}

impl TupleCache {
    /// Writes a cache: one binary file per split and the manifest (its `counts` are filled in
    /// here). Tuples are written in the given order.
    pub fn write(
        dir: &Path,
        mut manifest: Manifest,
        splits: &[(Split, Vec<CompactTuple>)],
    ) -> Result<Self, DataError> {
        std::fs::create_dir_all(dir).map_err(|e| DataError::io(dir, e))?;
        // The cache is a set: the manifest goes first and comes back last, so an interrupted
        // build leaves no manifest (the cache does not open) rather than an old manifest over
        // new files.
        let mpath = dir.join("manifest.json");
        if mpath.exists() {
            std::fs::remove_file(&mpath).map_err(|e| DataError::io(&mpath, e))?;
        }
        manifest.version = CACHE_VERSION;
        manifest.file_bytes.clear();
        manifest.counts = Split::ALL.iter().map(|s| (*s, 0)).collect();
        for split in Split::ALL {
            let tuples: &[CompactTuple] = splits
                .iter()
                .find(|(s, _)| *s == split)
                .map(|(_, t)| t.as_slice())
                .unwrap_or(&[]);
            let path = file_of(dir, split);
            let file = std::fs::File::create(&path).map_err(|e| DataError::io(&path, e))?;
            let mut w = BufWriter::new(file);
            let mut head = Vec::with_capacity(HEADER);
            head.extend_from_slice(MAGIC);
            head.extend_from_slice(&CACHE_VERSION.to_le_bytes());
            head.extend_from_slice(&(manifest.horizon as u32).to_le_bytes());
            head.extend_from_slice(&(tuples.len() as u64).to_le_bytes());
            w.write_all(&head).map_err(|e| DataError::io(&path, e))?;
            let mut buf = Vec::with_capacity(1024);
            for t in tuples {
                if t.future.len() != manifest.horizon {
                    return Err(DataError::Cache {
                        path,
                        message: format!(
                            "a tuple has {} future poses, the manifest says {}",
                            t.future.len(),
                            manifest.horizon
                        ),
                    });
                }
                buf.clear();
                encode(t, &mut buf);
                w.write_all(&buf).map_err(|e| DataError::io(&path, e))?;
            }
            w.flush().map_err(|e| DataError::io(&path, e))?;
            drop(w);
            let bytes = std::fs::metadata(&path)
                .map_err(|e| DataError::io(&path, e))?
                .len();
            manifest.counts.insert(split, tuples.len());
            manifest.file_bytes.insert(split, bytes);
        }
        let body = serde_json::to_string_pretty(&manifest).map_err(|e| DataError::Json {
            path: mpath.clone(),
            source: e,
        })?;
        let tmp = dir.join("manifest.json.partial");
        std::fs::write(&tmp, body).map_err(|e| DataError::io(&tmp, e))?;
        std::fs::rename(&tmp, &mpath).map_err(|e| DataError::io(&mpath, e))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// Opens a cache directory and checks its manifest version.
    pub fn open(dir: &Path) -> Result<TupleCache, DataError> {
        let mpath = dir.join("manifest.json");
        let body = read_user_file(&mpath, "cache manifest", MAX_MANIFEST_BYTES)
            .map_err(|e| DataError::io(&mpath, e))?;
        let manifest: Manifest = serde_json::from_str(&body).map_err(|e| DataError::Json {
            path: mpath.clone(),
            source: e,
        })?;
        if manifest.version != CACHE_VERSION {
            return Err(DataError::Cache {
                path: mpath,
                message: format!(
                    "cache version {} (this build reads {CACHE_VERSION}); rebuild it",
                    manifest.version
                ),
            });
        }
        manifest.bev.validate().map_err(|e| DataError::Cache {
            path: mpath.clone(),
            message: e.to_string(),
        })?;
        if manifest.horizon == 0 || manifest.horizon > MAX_HORIZON {
            return Err(DataError::Cache {
                path: mpath,
                message: format!(
                    "horizon {} is outside 1..={MAX_HORIZON} (tuples.horizon)",
                    manifest.horizon
                ),
            });
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
        })
    }

    /// The cache's manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// The cache directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Size of the cache files in bytes.
    pub fn size_bytes(&self) -> u64 {
        let mut n = std::fs::metadata(self.dir.join("manifest.json"))
            .map(|m| m.len())
            .unwrap_or(0);
        for s in Split::ALL {
            n += std::fs::metadata(file_of(&self.dir, s))
                .map(|m| m.len())
                .unwrap_or(0);
        }
        n
    }

    /// Reads the compact tuples of a split.
    pub fn load_compact(&self, split: Split) -> Result<Vec<CompactTuple>, DataError> {
        let path = file_of(&self.dir, split);
        let bytes = read_user_bytes(&path, "tuple cache file", MAX_CACHE_FILE_BYTES)
            .map_err(|e| DataError::io(&path, e))?;
        let bad = |message: String| DataError::Cache {
            path: path.clone(),
            message,
        };
        if let Some(&want) = self.manifest.file_bytes.get(&split)
            && bytes.len() as u64 != want
        {
            return Err(bad(format!(
                "{} bytes, the manifest says {want}: the file is not the one written with this \
                 manifest (an interrupted or concurrent build); rebuild the cache with \
                 `human2nav data build`",
                bytes.len()
            )));
        }
        if bytes.len() < HEADER || &bytes[..8] != MAGIC {
            return Err(bad("not a human2nav tuple file (bad magic)".into()));
        }
        let word =
            |a: usize| u32::from_le_bytes([bytes[a], bytes[a + 1], bytes[a + 2], bytes[a + 3]]);
        let (version, horizon) = (word(8), word(12) as usize);
        let mut c = [0u8; 8];
        c.copy_from_slice(&bytes[16..24]);
        let count = u64::from_le_bytes(c);
        if version != CACHE_VERSION || horizon != self.manifest.horizon {
            return Err(bad(format!(
                "file version {version} / horizon {horizon} do not match the manifest"
            )));
        }
        // Every tuple takes at least its fixed part and its future poses: a count the file
        // cannot hold is refused before anything is allocated for it.
        let least = horizon
            .checked_mul(12)
            .and_then(|f| f.checked_add(24))
            .unwrap_or(usize::MAX) as u64;
        let room = (bytes.len() - HEADER) as u64 / least.max(1);
        if count > room {
            return Err(bad(format!(
                "the header announces {count} tuples, the file has room for at most {room}"
            )));
        }
        let count = count as usize;
        if self.manifest.counts.get(&split).copied() != Some(count) {
            return Err(bad(format!(
                "holds {count} tuples, the manifest says {:?}",
                self.manifest.counts.get(&split)
            )));
        }
        let n_scenes = self.manifest.scenes.len();
        let mut r = Reader {
            b: &bytes,
            at: HEADER,
            path: &path,
        };
        let mut out = Vec::with_capacity(count);
        for _ in 0..count {
            let scene = r.u16()?;
            let cls = r.take(2)?[0];
            let n = r.u16()? as usize;
            r.take(2)?;
            if scene as usize >= n_scenes {
                return Err(bad(format!(
                    "scene index {scene} out of range ({n_scenes} scenes)"
                )));
            }
            let class = if cls == 255 {
                None
            } else {
                Some(
                    ScenarioClass::from_index(cls as usize)
                        .ok_or_else(|| bad(format!("bad class byte {cls}")))?,
                )
            };
            let goal = [r.f32()?, r.f32()?];
            let velocity = [r.f32()?, r.f32()?];
            let mut future = Vec::with_capacity(horizon);
            for _ in 0..horizon {
                future.push([r.f32()?, r.f32()?, r.f32()?]);
            }
            let mut agents = Vec::with_capacity(n);
            for _ in 0..n {
                agents.push([r.f32()?, r.f32()?, r.f32()?, r.f32()?, r.f32()?]);
            }
            out.push(CompactTuple {
                scene,
                class,
                goal,
                velocity,
                future,
                agents,
            });
        }
        if r.at != bytes.len() {
            return Err(bad(format!("{} trailing bytes", bytes.len() - r.at)));
        }
        Ok(out)
    }

    /// Reads the dense tuples of a split (rasters drawn in parallel; order as stored).
    pub fn load(&self, split: Split) -> Result<Vec<TrainingTuple>, DataError> {
        let spec = self.manifest.bev;
        Ok(self
            .load_compact(split)?
            .par_iter()
            .map(|t| t.to_tuple(&spec))
            .collect())
    }

    /// The scenes [`TupleCache::load_scenes`] keeps: `max(1, round(fraction · n))` of the split's
    /// `n` scenes, drawn by a seeded shuffle (the same seed and fraction always pick the same
    /// scenes, and a larger fraction keeps every scene of a smaller one).
    pub fn pick_scenes(
        &self,
        split: Split,
        fraction: f64,
        seed: u64,
    ) -> Result<Vec<u16>, DataError> {
        if !(fraction.is_finite() && fraction > 0.0 && fraction <= 1.0) {
            return Err(DataError::option(
                "fraction",
                format!("must be in (0, 1], got {fraction}"),
            ));
        }
        let mut scenes = self.manifest.scenes_in(split);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        scenes.shuffle(&mut rng);
        let keep = ((fraction * scenes.len() as f64).round() as usize)
            .clamp(1.min(scenes.len()), scenes.len());
        scenes.truncate(keep);
        scenes.sort_unstable();
        Ok(scenes)
    }

    /// Dense tuples of a fraction of the split's scenes (data-efficiency experiments).
    pub fn load_scenes(
        &self,
        split: Split,
        fraction: f64,
        seed: u64,
    ) -> Result<Vec<TrainingTuple>, DataError> {
        let keep = self.pick_scenes(split, fraction, seed)?;
        let spec = self.manifest.bev;
        Ok(self
            .load_compact(split)?
            .par_iter()
            .filter(|t| keep.binary_search(&t.scene).is_ok())
            .map(|t| t.to_tuple(&spec))
            .collect())
    }

    /// Per-scene tuple counts by class: `scene index → [co, cross, counter, multi, none]`.
    pub fn class_counts(tuples: &[CompactTuple]) -> BTreeMap<u16, [usize; 5]> {
        let mut m: BTreeMap<u16, [usize; 5]> = BTreeMap::new();
        for t in tuples {
            m.entry(t.scene).or_default()[t.class.map(|c| c.index()).unwrap_or(4)] += 1;
        }
        m
    }
}

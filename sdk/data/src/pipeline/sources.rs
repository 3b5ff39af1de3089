//! The dataset files of a job: which scenes the enabled sources have under the data root
//! ([`discover`]) and how each is read ([`load_source`]).

use crate::config::DataConfig;
use crate::error::DataError;
use crate::loaders::{eth, sdd, sgan, ucy};
use crate::track::RawScene;
use std::path::{Path, PathBuf};

/// How to read one source file.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceKind {
    /// An ETH (EWAP) `obsmat.txt`: world coordinates at 2.5 fps.
    EwapObsmat {
        /// The file.
        path: PathBuf,
    },
    /// A UCY `.vsp` spline file in image coordinates.
    UcyVsp {
        /// The file.
        path: PathBuf,
        /// The UCY folder, where the scene's homography is looked up.
        ucy_root: PathBuf,
        /// The scene (`zara01`, ...).
        scene: String,
    },
    /// A Social-GAN benchmark file (`frame id x y`, world coordinates).
    Sgan {
        /// The file.
        path: PathBuf,
    },
    /// A Stanford Drone Dataset `annotations.txt` (pixel boxes at 30 fps).
    SddRaw {
        /// The file.
        path: PathBuf,
        /// The metres-per-pixel scale file.
        scales: PathBuf,
        /// The video (`scene/videoN`) whose scale applies.
        video: String,
    },
    /// A TrajNet conversion of SDD (world coordinates).
    SddTrajnet {
        /// The file.
        path: PathBuf,
    },
}

/// One scene to load.
#[derive(Clone, Debug, PartialEq)]
pub struct Source {
    /// `dataset/scene`.
    pub name: String,
    /// Its file and how to read it.
    pub kind: SourceKind,
}

/// UCY scenes with a usable homography (arxiepiskopi's unit is unknown).
pub const UCY_SCENES: [&str; 6] = [
    "zara01",
    "zara02",
    "zara03",
    "students01",
    "students03",
    "uni_examples",
];

fn sorted_dir(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .collect();
    v.sort();
    v
}

/// Lists the scenes of the enabled sources under `root`, sorted by name, with notes on
/// sources that were enabled but not found.
pub fn discover(root: &Path, cfg: &DataConfig) -> (Vec<Source>, Vec<String>) {
    let mut out = Vec::new();
    let mut notes = Vec::new();
    let s = &cfg.sources;
    if s.eth {
        for (seq, scene) in [("seq_eth", "eth"), ("seq_hotel", "hotel")] {
            let path = root
                .join("eth_ucy/opentraj_raw/ETH")
                .join(seq)
                .join("obsmat.txt");
            if path.is_file() {
                out.push(Source {
                    name: format!("eth/{scene}"),
                    kind: SourceKind::EwapObsmat { path },
                });
            } else {
                notes.push(format!("eth: {} not found", path.display()));
            }
        }
    }
    if s.ucy {
        let ucy_root = root.join("eth_ucy/opentraj_raw/UCY");
        for scene in UCY_SCENES {
            let path = ucy_root.join(scene).join("annotation.vsp");
            if path.is_file() {
                out.push(Source {
                    name: format!("ucy/{scene}"),
                    kind: SourceKind::UcyVsp {
                        path,
                        ucy_root: ucy_root.clone(),
                        scene: scene.to_string(),
                    },
                });
            } else {
                notes.push(format!("ucy: {} not found", path.display()));
            }
        }
    }
    let mut sdd_videos: Vec<String> = Vec::new();
    if s.sdd_raw {
        let base = root.join("sdd/opentraj_raw");
        let scales = base.join("estimated_scales.yaml");
        for scene_dir in sorted_dir(&base).into_iter().filter(|p| p.is_dir()) {
            for video_dir in sorted_dir(&scene_dir) {
                let path = video_dir.join("annotations.txt");
                if !path.is_file() {
                    continue;
                }
                let scene = scene_dir
                    .file_name()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let n = video_dir
                    .file_name()
                    .map(|s| s.to_string_lossy().trim_start_matches("video").to_string())
                    .unwrap_or_default();
                let video = format!("{scene}_{n}");
                sdd_videos.push(video.clone());
                out.push(Source {
                    name: format!("sdd/{video}"),
                    kind: SourceKind::SddRaw {
                        path,
                        scales: scales.clone(),
                        video,
                    },
                });
            }
        }
        if sdd_videos.is_empty() {
            notes.push(format!("sdd_raw: no annotations under {}", base.display()));
        }
    }
    if s.sdd_trajnet {
        let base = root.join("sdd/trajnet_split_socialvae");
        let mut found = false;
        for split in ["train", "test"] {
            for path in sorted_dir(&base.join(split)) {
                if path.extension().is_none_or(|e| e != "txt") {
                    continue;
                }
                found = true;
                let video = path
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                if sdd_videos.contains(&video) {
                    continue; // the raw annotations of this video are used instead
                }
                out.push(Source {
                    name: format!("sdd/{video}"),
                    kind: SourceKind::SddTrajnet { path },
                });
            }
        }
        if !found {
            notes.push(format!("sdd_trajnet: no files under {}", base.display()));
        }
    }
    if s.sgan {
        let base = root.join("eth_ucy/trajectron_sgan_format/raw/all_data");
        for path in sorted_dir(&base) {
            let stem = path
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            out.push(Source {
                name: format!("sgan/{stem}"),
                kind: SourceKind::Sgan { path },
            });
        }
    }
    out.sort_by(|a, b| a.name.cmp(&b.name));
    (out, notes)
}

/// Loads one source as a raw scene.
pub fn load_source(src: &Source, cfg: &DataConfig) -> Result<RawScene, DataError> {
    match &src.kind {
        SourceKind::EwapObsmat { path } => eth::load_obsmat(path, &src.name),
        SourceKind::UcyVsp {
            path,
            ucy_root,
            scene,
        } => {
            let h = ucy::load_homography(ucy_root, scene)?;
            ucy::load_vsp(path, &h, ucy::VspConvention::of(scene), &src.name)
        }
        SourceKind::Sgan { path } => sgan::load(path, &src.name, "sgan"),
        SourceKind::SddRaw {
            path,
            scales,
            video,
        } => {
            let scale = sdd::SddScales::load(scales)?.scale(video)?;
            sdd::load_raw(path, scale, &src.name, &cfg.sdd)
        }
        SourceKind::SddTrajnet { path } => sdd::load_trajnet(path, &src.name),
    }
}

//! Checkpoints (one file set each, see the `train` module docs) and resuming from them.

use super::{Progress, TrainConfig, Trainer};
use crate::error::SarlError;
use crate::state::JOINT_DIM;
use human2nav_core::fileset::{self, SetError};
use human2nav_core::input::{MAX_CONFIG_BYTES, read_user_file};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use tch::{Kind, Tensor};

/// Names of the checkpoint files inside the run directory.
pub(super) const CKPT_DIR: &str = "checkpoint";
pub(super) const CKPT_MODEL: &str = "model.safetensors";
pub(super) const CKPT_TARGET: &str = "target.safetensors";
pub(super) const CKPT_MOMENTUM: &str = "momentum.safetensors";
pub(super) const CKPT_MEMORY: &str = "memory.safetensors";
pub(super) const CKPT_PROGRESS: &str = "progress.toml";
/// Every file of a checkpoint set, all listed in its manifest.
pub(super) const CKPT_FILES: [&str; 5] = [
    CKPT_MODEL,
    CKPT_TARGET,
    CKPT_MOMENTUM,
    CKPT_MEMORY,
    CKPT_PROGRESS,
];

impl Trainer {
    /// Resumes from the newest complete checkpoint set under `out_dir` (`checkpoint/`, or
    /// `checkpoint.old/` when a save was cut between its renames); `None` when there is no
    /// checkpoint at all. A partial set (a file missing, or not the size and checksum its
    /// manifest records) is an error naming the file.
    pub fn resume(cfg: TrainConfig, out_dir: PathBuf) -> Result<Option<Self>, SarlError> {
        let ckpt = out_dir.join(CKPT_DIR);
        let dir = match fileset::find_complete(&ckpt, &CKPT_FILES) {
            Ok(Some(dir)) => dir,
            Ok(None) => return Ok(None),
            Err(SetError::Incomplete { path, reason }) => {
                return Err(SarlError::Resume {
                    path,
                    message: format!(
                        "{reason}; the checkpoint set is incomplete (restore it, or start \
                         afresh without --resume)"
                    ),
                });
            }
            Err(e) => return Err(e.into()),
        };
        let progress_path = dir.join(CKPT_PROGRESS);
        let mut t = Self::new(cfg, out_dir)?;
        let text = read_user_file(&progress_path, "SARL training progress", MAX_CONFIG_BYTES)
            .map_err(|e| SarlError::io(&progress_path, e))?;
        let progress: Progress = toml::from_str(&text).map_err(|e| SarlError::Parse {
            path: progress_path.clone(),
            message: e.to_string(),
        })?;
        if progress.config_key != t.progress.config_key {
            return Err(SarlError::Resume {
                path: progress_path,
                message: "the checkpoint was written under different settings (only `run` and \
                          `rl.episodes` may change); start afresh without --resume or restore \
                          the old settings"
                    .into(),
            });
        }
        t.model.load(&dir.join(CKPT_MODEL))?;
        t.target.load(&dir.join(CKPT_TARGET))?;
        let named = read_tensors(&dir.join(CKPT_MOMENTUM))?;
        for (k, buf) in t.momentum.iter_mut() {
            let Some(saved) = named.get(k) else {
                return Err(SarlError::Resume {
                    path: dir.join(CKPT_MOMENTUM),
                    message: format!("no momentum buffer `{k}`"),
                });
            };
            *buf = saved.shallow_clone();
        }
        let mem = read_tensors(&dir.join(CKPT_MEMORY))?;
        let (Some(states), Some(values)) = (mem.get("states"), mem.get("values")) else {
            return Err(SarlError::Resume {
                path: dir.join(CKPT_MEMORY),
                message: "needs tensors `states` and `values`".into(),
            });
        };
        t.memory.states = Vec::<f32>::try_from(&states.reshape([-1]))?;
        t.memory.values = Vec::<f32>::try_from(&values.reshape([-1]))?;
        t.memory.next = progress.memory_next;
        if t.memory.states.len() != t.memory.values.len() * t.memory.stride
            || t.memory.values.len() > t.memory.capacity
        {
            return Err(SarlError::Resume {
                path: dir.join(CKPT_MEMORY),
                message: "memory shape does not fit the settings".into(),
            });
        }
        t.progress = progress;
        Ok(Some(t))
    }

    /// Writes the checkpoint as one set (module docs): a crash at any point leaves a complete
    /// set behind, the new one or the previous one.
    pub fn checkpoint(&mut self) -> Result<(), SarlError> {
        self.progress.memory_next = self.memory.next;
        let step = (self.progress.il_epochs_done + self.progress.rl_episodes_done) as u64;
        let ckpt = self.out_dir.join(CKPT_DIR);
        fileset::commit(&ckpt, &CKPT_FILES, step, |dir| self.write_checkpoint(dir))
    }

    /// Writes the checkpoint's files into `dir` (no manifest).
    fn write_checkpoint(&self, dir: &Path) -> Result<(), SarlError> {
        self.model.save(&dir.join(CKPT_MODEL))?;
        self.target.save(&dir.join(CKPT_TARGET))?;
        let named: Vec<(String, Tensor)> = self
            .momentum
            .iter()
            .map(|(k, v)| (k.clone(), v.shallow_clone()))
            .collect();
        write_tensors(&dir.join(CKPT_MOMENTUM), &named)?;
        let m = &self.memory;
        let rows = m.values.len() as i64;
        let states = Tensor::from_slice(&m.states).reshape([
            rows,
            (m.stride / JOINT_DIM) as i64,
            JOINT_DIM as i64,
        ]);
        let values = Tensor::from_slice(&m.values);
        write_tensors(
            &dir.join(CKPT_MEMORY),
            &[
                ("states".to_string(), states),
                ("values".to_string(), values),
            ],
        )?;
        let path = dir.join(CKPT_PROGRESS);
        let text = toml::to_string(&self.progress).map_err(|e| SarlError::Parse {
            path: path.clone(),
            message: e.to_string(),
        })?;
        let tmp = path.with_extension("toml.tmp");
        std::fs::write(&tmp, text).map_err(|e| SarlError::io(&tmp, e))?;
        std::fs::rename(&tmp, &path).map_err(|e| SarlError::io(&path, e))
    }
}

/// Reads every tensor of a safetensors file by name.
fn read_tensors(path: &Path) -> Result<BTreeMap<String, Tensor>, SarlError> {
    if !path.is_file() {
        return Err(SarlError::Resume {
            path: path.to_path_buf(),
            message: "file missing".into(),
        });
    }
    let list = Tensor::read_safetensors(path).map_err(|e| SarlError::Weights {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    Ok(list.into_iter().collect())
}

/// Writes named tensors as safetensors (temporary file, then rename).
fn write_tensors(path: &Path, tensors: &[(String, Tensor)]) -> Result<(), SarlError> {
    let tmp = path.with_extension("tmp.safetensors");
    let contiguous: Vec<(String, Tensor)> = tensors
        .iter()
        .map(|(k, t)| (k.clone(), t.to_kind(Kind::Float).contiguous()))
        .collect();
    Tensor::write_safetensors(&contiguous, &tmp).map_err(|e| SarlError::Weights {
        path: tmp.clone(),
        message: e.to_string(),
    })?;
    std::fs::rename(&tmp, path).map_err(|e| SarlError::io(path, e))
}

use super::checkpoint::{CKPT_DIR, CKPT_FILES, CKPT_MEMORY, CKPT_MODEL, CKPT_PROGRESS};
use super::*;
use crate::net::NetConfig;
use crate::state::JOINT_DIM;
use human2nav_core::fileset;
use std::path::Path;

fn small(dir: &str) -> (TrainConfig, PathBuf) {
    let mut c = TrainConfig::default();
    c.il.episodes = 30;
    c.il.epochs = 4;
    c.rl.episodes = 6;
    c.rl.batches_per_episode = 3;
    c.rl.target_update_every = 2;
    c.run.checkpoint_every = 3;
    c.run.eval_every = 3;
    c.run.eval_episodes = 2;
    let out = std::env::temp_dir().join(format!("human2nav-sarl-{dir}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    (c, out)
}

fn weights(t: &Trainer) -> Vec<(String, Vec<f32>)> {
    let mut v: Vec<(String, Vec<f32>)> = t
        .model
        .var_store()
        .variables()
        .into_iter()
        .map(|(k, x)| (k, Vec::<f32>::try_from(&x.reshape([-1])).unwrap()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    v
}

#[test]
fn imitation_lowers_the_value_loss() {
    let (cfg, out) = small("il");
    let mut t = Trainer::new(cfg, out.clone()).unwrap();
    t.run(&mut Silent).unwrap();
    let log = &t.progress().il_log;
    assert_eq!(log.len(), 4);
    let (first, last) = (log[0].loss, log[3].loss);
    assert!(first.is_finite() && last.is_finite());
    assert!(last < 0.8 * first, "imitation loss {first} → {last}");
    // The demonstrations that did not time out, then the TD episodes, filled the memory.
    assert!(t.progress().demo_transitions > 0);
    assert!(t.memory().len() > t.progress().demo_transitions);
    // The TD stage ran and logged at every checkpoint.
    assert_eq!(t.progress().rl_episodes_done, 6);
    assert_eq!(t.progress().rl_log.len(), 2);
    assert!(t.progress().rl_log.iter().all(|p| p.loss.is_finite()));
    // Validation after imitation and at episodes 3 and 6.
    assert_eq!(
        t.progress()
            .validation
            .iter()
            .map(|v| v.episode)
            .collect::<Vec<_>>(),
        vec![0, 3, 6]
    );
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn runs_are_deterministic_and_resume_exactly() {
    let (cfg, out_a) = small("det-a");
    let mut a = Trainer::new(cfg.clone(), out_a.clone()).unwrap();
    a.run(&mut Silent).unwrap();

    // The same run interrupted after three TD episodes (a checkpoint), then resumed.
    let (_, out_b) = small("det-b");
    let mut first = cfg.clone();
    first.rl.episodes = 3;
    let mut b = Trainer::new(first, out_b.clone()).unwrap();
    b.run(&mut Silent).unwrap();
    drop(b);
    let mut b = Trainer::resume(cfg.clone(), out_b.clone())
        .unwrap()
        .unwrap();
    assert_eq!(b.progress().rl_episodes_done, 3);
    b.run(&mut Silent).unwrap();

    assert_eq!(a.progress().il_log, b.progress().il_log);
    assert_eq!(a.progress().rl_log, b.progress().rl_log);
    assert_eq!(a.progress().validation, b.progress().validation);
    assert_eq!(a.memory(), b.memory());
    assert_eq!(weights(&a), weights(&b));
    let _ = std::fs::remove_dir_all(&out_a);
    let _ = std::fs::remove_dir_all(&out_b);
}

#[test]
fn resume_refuses_other_settings() {
    let (cfg, out) = small("refuse");
    let mut c = cfg.clone();
    c.rl.episodes = 0;
    c.run.eval_episodes = 0;
    let mut t = Trainer::new(c.clone(), out.clone()).unwrap();
    t.run(&mut Silent).unwrap();
    let mut other = c.clone();
    other.optim.gamma = 0.8;
    let err = Trainer::resume(other, out.clone()).unwrap_err();
    assert!(matches!(err, SarlError::Resume { .. }), "{err}");
    // No checkpoint: nothing to resume.
    assert!(Trainer::resume(c, out.join("nowhere")).unwrap().is_none());
    let _ = std::fs::remove_dir_all(&out);
}

/// A run stopped after imitation (no TD episodes): its checkpoint is a complete set.
fn stopped_run(name: &str) -> (TrainConfig, PathBuf) {
    let (mut c, out) = small(name);
    c.rl.episodes = 0;
    c.run.eval_episodes = 0;
    Trainer::new(c.clone(), out.clone())
        .unwrap()
        .run(&mut Silent)
        .unwrap();
    (c, out)
}

#[test]
fn checkpoints_are_sets_with_a_manifest() {
    let (c, out) = stopped_run("set");
    let ckpt = out.join(CKPT_DIR);
    let manifest = std::fs::read_to_string(ckpt.join(fileset::MANIFEST_FILE)).unwrap();
    for f in CKPT_FILES {
        assert!(manifest.contains(&format!("[files.\"{f}\"]")), "{manifest}");
    }
    assert!(!fileset::sibling(&ckpt, "partial").exists());
    let t = Trainer::resume(c.clone(), out.clone()).unwrap().unwrap();
    assert_eq!(t.progress().il_epochs_done, 4);
    // Killed between the two renames of a later save: `checkpoint.old` is the last complete
    // set, and the half-filled `checkpoint` beside it is ignored.
    let old = fileset::sibling(&ckpt, "old");
    std::fs::rename(&ckpt, &old).unwrap();
    std::fs::create_dir_all(&ckpt).unwrap();
    std::fs::copy(old.join(CKPT_MODEL), ckpt.join(CKPT_MODEL)).unwrap();
    let t = Trainer::resume(c, out.clone()).unwrap().unwrap();
    assert_eq!(t.progress().il_epochs_done, 4);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_partial_checkpoint_is_refused_naming_the_file() {
    let (c, out) = stopped_run("partial");
    let ckpt = out.join(CKPT_DIR);
    // The progress file gone: this resumed as "no checkpoint" (a silent restart) before.
    std::fs::remove_file(ckpt.join(CKPT_PROGRESS)).unwrap();
    let err = Trainer::resume(c.clone(), out.clone()).unwrap_err();
    assert!(
        matches!(&err, SarlError::Resume { .. })
            && err.to_string().contains("progress.toml is missing")
            && err.to_string().contains("without --resume"),
        "{err}"
    );
    // An altered memory file: named with its size and the manifest's.
    let (c2, out2) = stopped_run("altered");
    let mem = out2.join(CKPT_DIR).join(CKPT_MEMORY);
    let mut bytes = std::fs::read(&mem).unwrap();
    bytes.truncate(bytes.len() / 2);
    std::fs::write(&mem, &bytes).unwrap();
    let err = Trainer::resume(c2, out2.clone()).unwrap_err().to_string();
    assert!(
        err.contains("memory.safetensors has") && err.contains("the manifest says"),
        "{err}"
    );
    // Without a manifest, the files of an older checkpoint: missing ones are named too.
    std::fs::remove_file(ckpt.join(fileset::MANIFEST_FILE)).unwrap();
    let err = Trainer::resume(c, out.clone()).unwrap_err().to_string();
    assert!(err.contains("progress.toml is missing"), "{err}");
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&out2);
}

#[test]
fn epsilon_schedule() {
    let r = RlConfig::default();
    assert_eq!(r.epsilon(0), 0.5);
    approx::assert_relative_eq!(r.epsilon(2000), 0.3, epsilon = 1e-12);
    assert_eq!(r.epsilon(4000), 0.1);
    assert_eq!(r.epsilon(15000), 0.1);
}

#[test]
fn memory_is_a_ring() {
    let mut m = Memory::new(3, 1);
    for k in 0..5 {
        m.push(&[k as f32; JOINT_DIM], k as f32);
    }
    assert_eq!(m.len(), 3);
    // Pushes 3 and 4 overwrote slots 0 and 1.
    assert_eq!(m.values, vec![3.0, 4.0, 2.0]);
    assert_eq!(m.states[0], 3.0);
    assert_eq!(m.next, 2);
}

#[test]
fn the_shipped_config_parses() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../sdk/configs/sarl.toml");
    let cfg = TrainConfig::load(&path).unwrap();
    assert_eq!(cfg.il.episodes, 5000);
    assert_eq!(cfg.net, NetConfig::default());
    let err = toml::from_str::<TrainConfig>("[rl]\nepisodez = 3").unwrap_err();
    assert!(err.to_string().contains("episodez"), "{err}");
    // Thread counts are bounded (libtorch would start them all).
    for threads in [0, MAX_THREADS + 1, 100_000] {
        let c = TrainConfig {
            threads,
            ..cfg.clone()
        };
        let err = c.validate().unwrap_err().to_string();
        assert!(err.contains("threads") && err.contains("1..=256"), "{err}");
    }
}

//! The model folder and the configurations read by crates that link libtorch: the planner's
//! (`human2nav-flow`), training and the scaling experiment (`human2nav-experiments`) and SARL's
//! training (`human2nav-sarl`). Built with the default feature `model`.

use super::seeds_of;
use crate::{Scratch, Target};
use human2nav_flow::ModelCard;
use human2nav_flow::planner::{Backend, PlannerConfig, load_model};

const CARD: &str = include_str!("../../../models/human2nav-cfm/model.toml");
const WEIGHTS: &[u8] = include_bytes!("../../../models/human2nav-cfm/model.safetensors");
const PLANNER_TOML: &str = include_str!("../../../sdk/configs/planner.toml");
const TRAIN_TOML: &str = include_str!("../../../sdk/configs/train.toml");
const SCALING_TOML: &str = include_str!("../../../sdk/configs/scaling.toml");
const SARL_TOML: &str = include_str!("../../../sdk/configs/sarl.toml");

pub(crate) fn targets() -> Vec<Target> {
    vec![
        Target {
            name: "model_card",
            covers: "the shipped model card (models/human2nav-cfm/model.toml) through \
                     ModelCard::load (format version, [net], [normalisation], [bev] against \
                     net.bev_cells); one input in eight also loads the folder with the shipped \
                     weights through the native backend (checksum, tensor names and shapes)",
            seeds: || seeds_of(&[CARD]),
            exec: model_card,
        },
        Target {
            name: "planner_config",
            covers: "the whole sdk/configs/planner.toml (model, threads, backend and every \
                     [human2nav] table) through PlannerConfig::load",
            seeds: || seeds_of(&[PLANNER_TOML]),
            exec: planner_config,
        },
        Target {
            name: "train_toml",
            covers: "sdk/configs/train.toml through human2nav_experiments' TrainConfig::load and \
                     validate",
            seeds: || seeds_of(&[TRAIN_TOML]),
            exec: train_toml,
        },
        Target {
            name: "scaling_toml",
            covers: "sdk/configs/scaling.toml through ScalingConfig::load",
            seeds: || seeds_of(&[SCALING_TOML]),
            exec: scaling_toml,
        },
        Target {
            name: "sarl_toml",
            covers: "sdk/configs/sarl.toml through human2nav_sarl's TrainConfig::load",
            seeds: || seeds_of(&[SARL_TOML]),
            exec: sarl_toml,
        },
    ]
}

fn train_toml(s: &Scratch, input: &[u8]) {
    let path = s.write("train.toml", input);
    if let Ok(cfg) = human2nav_experiments::train::TrainConfig::load(&path) {
        let _ = cfg.validate();
    }
}

fn scaling_toml(s: &Scratch, input: &[u8]) {
    let path = s.write("scaling.toml", input);
    let _ = human2nav_experiments::scaling::ScalingConfig::load(&path);
}

fn sarl_toml(s: &Scratch, input: &[u8]) {
    let path = s.write("sarl.toml", input);
    if let Ok(cfg) = human2nav_sarl::train::TrainConfig::load(&path) {
        // Whatever loads has passed its own validation; it must pass it again.
        assert!(cfg.validate().is_ok(), "a loaded sarl.toml fails validate");
    }
}

fn model_card(s: &Scratch, input: &[u8]) {
    let path = s.write("model/model.toml", input);
    let card = ModelCard::load(&path);
    if crate::fnv(input) % 8 == 0 {
        let dir = s.dir().join("model");
        if !dir.join("model.safetensors").is_file() {
            s.write("model/model.safetensors", WEIGHTS);
        }
        let loaded = load_model(&dir, Backend::Native);
        // A folder whose card does not load cannot load as a model either.
        assert!(
            card.is_ok() || loaded.is_err(),
            "a card refused by ModelCard::load was accepted by load_model"
        );
    }
}

fn planner_config(s: &Scratch, input: &[u8]) {
    let path = s.write("planner.toml", input);
    if let Ok(cfg) = PlannerConfig::load(&path) {
        // Whatever loads is valid, and its model folder resolves.
        assert!(
            cfg.validate().is_ok(),
            "a loaded planner.toml fails validate"
        );
        let _ = cfg.model_dir(s.dir());
    }
}

//! The model folder and the planner configuration, as `human2nav-flow` reads them (built with
//! the default feature `model`, which needs libtorch).

use super::seeds_of;
use crate::{Scratch, Target};
use human2nav_flow::ModelCard;
use human2nav_flow::planner::{Backend, PlannerConfig, load_model};

const CARD: &str = include_str!("../../../models/human2nav-cfm/model.toml");
const WEIGHTS: &[u8] = include_bytes!("../../../models/human2nav-cfm/model.safetensors");
const PLANNER_TOML: &str = include_str!("../../../sdk/configs/planner.toml");

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
    ]
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

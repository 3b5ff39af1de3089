//! The export of a trained network: test evaluation, weights, model card and curve.

use super::Trainer;
use crate::card::{
    CARD_FILE, CURVE_FILE, EvalCard, LookAheadCard, ModelCard, TrainingCard, WEIGHTS_FILE,
};
use crate::error::SarlError;
use crate::eval::{Policy, SeedStream, evaluate};
use std::path::Path;

impl Trainer {
    /// Evaluates the trained network on the held-out test stream (and the straight and ORCA
    /// policies on the same episodes), then writes `model.safetensors`, `model.toml` and the
    /// training-curve PNG into `model_dir`.
    pub fn export(
        &self,
        model_dir: &Path,
        progress: &mut dyn FnMut(&str, usize),
    ) -> Result<ModelCard, SarlError> {
        std::fs::create_dir_all(model_dir).map_err(|e| SarlError::io(model_dir, e))?;
        let n = self.cfg.run.test_episodes;
        let env = &self.cfg.env;
        let seed = self.cfg.seed;
        let sarl = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: 0.0,
        };
        let s = evaluate(env, &sarl, seed, SeedStream::Test, n, &mut |i| {
            progress("sarl", i)
        })?;
        let st = evaluate(
            env,
            &Policy::Straight,
            seed,
            SeedStream::Test,
            n,
            &mut |i| progress("straight", i),
        )?;
        let orca = Policy::Orca {
            safety_space: self.cfg.il.safety_space,
        };
        let o = evaluate(env, &orca, seed, SeedStream::Test, n, &mut |i| {
            progress("orca", i)
        })?;
        self.model.save(&model_dir.join(WEIGHTS_FILE))?;
        let c = &self.cfg;
        let card = ModelCard {
            format_version: 1,
            name: c.run.name.clone(),
            description: "SARL value network (Chen et al. 2019, CrowdNav defaults): pairwise \
                          human-robot embedding mlp1, feature mlp2, attention over [e_i, mean e] \
                          with softmax pooling, value head mlp3 on [self state, pooled feature]; \
                          holonomic one-step look-ahead over 81 actions. Trained by imitation of \
                          ORCA, then TD learning in circle crossing."
                .into(),
            weights: WEIGHTS_FILE.into(),
            parameters: c.net.parameter_count(),
            net: c.net.clone(),
            lookahead: LookAheadCard {
                gamma: c.optim.gamma,
                time_step: c.env.time_step,
                speed_samples: crate::action::SPEED_SAMPLES,
                rotation_samples: crate::action::ROTATION_SAMPLES,
                v_pref: c.env.robot_v_pref,
            },
            reward: c.env.reward(),
            env: c.env.clone(),
            training: TrainingCard {
                seed: c.seed,
                threads: c.threads,
                il_episodes: c.il.episodes,
                il_transitions: self.progress.demo_transitions,
                il_epochs: c.il.epochs,
                il_learning_rate: c.il.learning_rate,
                rl_episodes: self.progress.rl_episodes_done,
                rl_learning_rate: c.rl.learning_rate,
                batches_per_episode: c.rl.batches_per_episode,
                batch_size: c.optim.batch_size,
                momentum: c.optim.momentum,
                capacity: c.optim.capacity,
                epsilon: format!(
                    "{} → {} linearly over {} episodes",
                    c.rl.epsilon_start, c.rl.epsilon_end, c.rl.epsilon_decay_episodes
                ),
                target_update_every: c.rl.target_update_every,
                wall_seconds: self.progress.wall_seconds,
                notes: c.run.notes.clone(),
            },
            evaluation: EvalCard {
                episodes: n,
                seeds: format!("held-out test stream of seed {seed}, episodes 0..{n}"),
                success_rate: s.success_rate,
                collision_rate: s.collision_rate,
                timeout_rate: s.timeout_rate,
                mean_success_time: s.mean_success_time,
                straight_success_rate: st.success_rate,
                straight_collision_rate: st.collision_rate,
                orca_success_rate: o.success_rate,
                orca_collision_rate: o.collision_rate,
            },
        };
        card.save(&model_dir.join(CARD_FILE))?;
        crate::plot::training_curve(&self.progress, &model_dir.join(CURVE_FILE))?;
        Ok(card)
    }
}

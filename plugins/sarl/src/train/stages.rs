//! The two training stages: ORCA demonstrations and imitation epochs, then TD episodes.

use super::{LogPoint, Observer, Trainer, ValPoint};
use crate::env::Outcome;
use crate::error::SarlError;
use crate::eval::{EvalStats, Policy, SeedStream, episode_rng, evaluate, run_episode};
use crate::state::JOINT_DIM;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

impl Trainer {
    /// Runs (or continues) both stages to the end, checkpointing on the way.
    pub fn run(&mut self, obs: &mut dyn Observer) -> Result<(), SarlError> {
        let start = Instant::now();
        let wall0 = self.progress.wall_seconds;
        let clock = || wall0 + start.elapsed().as_secs_f64();
        if !self.progress.demos_done {
            self.generate_demonstrations(obs)?;
            self.progress.wall_seconds = clock();
            obs.note(&format!(
                "demonstrations done (wall {:.0} s)",
                self.progress.wall_seconds
            ));
            self.checkpoint()?;
        }
        if self.progress.il_epochs_done < self.cfg.il.epochs {
            obs.stage(
                "imitation epochs",
                self.cfg.il.epochs as u64,
                self.progress.il_epochs_done as u64,
            );
            while self.progress.il_epochs_done < self.cfg.il.epochs {
                let loss = self.il_epoch(self.progress.il_epochs_done)?;
                self.progress.il_epochs_done += 1;
                let e = self.progress.il_epochs_done;
                self.progress.il_log.push(LogPoint {
                    step: e,
                    loss,
                    success_rate: 0.0,
                });
                obs.tick(e as u64, &format!("loss {loss:.5}"));
                if e % 10 == 0 || e == self.cfg.il.epochs {
                    self.progress.wall_seconds = clock();
                    self.checkpoint()?;
                }
            }
            self.target.copy_from(&self.model)?;
            obs.note(&format!("imitation done (wall {:.0} s)", clock()));
        }
        if self.progress.validation.is_empty() && self.cfg.run.eval_episodes > 0 {
            let s = self.validate(obs)?;
            obs.note(&format!(
                "after imitation: validation success {:.3}, collision {:.3}, timeout {:.3}",
                s.success_rate, s.collision_rate, s.timeout_rate
            ));
        }
        let total = self.cfg.rl.episodes;
        if self.progress.rl_episodes_done < total {
            obs.stage(
                "TD episodes",
                total as u64,
                self.progress.rl_episodes_done as u64,
            );
        }
        let mut block_loss = Vec::new();
        let mut block_outcomes = Vec::new();
        let mut recent: std::collections::VecDeque<bool> = std::collections::VecDeque::new();
        while self.progress.rl_episodes_done < total {
            let e = self.progress.rl_episodes_done;
            let (outcome, loss) = self.rl_episode(e)?;
            block_loss.push(loss);
            block_outcomes.push(outcome);
            recent.push_back(outcome == Outcome::Success);
            if recent.len() > 100 {
                recent.pop_front();
            }
            self.progress.rl_episodes_done += 1;
            let done = self.progress.rl_episodes_done;
            if done % self.cfg.rl.target_update_every == 0 {
                self.target.copy_from(&self.model)?;
            }
            let sr = recent.iter().filter(|s| **s).count() as f64 / recent.len() as f64;
            obs.tick(
                done as u64,
                &format!(
                    "ε {:.2}  train success (last {}) {:.2}  loss {:.5}",
                    self.cfg.rl.epsilon(e),
                    recent.len(),
                    sr,
                    loss
                ),
            );
            if done % self.cfg.run.eval_every == 0 && self.cfg.run.eval_episodes > 0 {
                let s = self.validate(obs)?;
                obs.note(&format!(
                    "episode {done}: validation success {:.3}, collision {:.3}, timeout {:.3}",
                    s.success_rate, s.collision_rate, s.timeout_rate
                ));
            }
            if done % self.cfg.run.checkpoint_every == 0 || done == total {
                let n = block_outcomes.len().max(1) as f64;
                self.progress.rl_log.push(LogPoint {
                    step: done,
                    loss: block_loss.iter().sum::<f64>() / n,
                    success_rate: block_outcomes
                        .iter()
                        .filter(|o| **o == Outcome::Success)
                        .count() as f64
                        / n,
                });
                block_loss.clear();
                block_outcomes.clear();
                self.progress.wall_seconds = clock();
                self.checkpoint()?;
                obs.note(&format!(
                    "episode {done}: checkpoint written (wall {:.0} s)",
                    self.progress.wall_seconds
                ));
            }
        }
        self.progress.wall_seconds = clock();
        Ok(())
    }

    /// Stage 1a: the ORCA demonstrations into the memory.
    fn generate_demonstrations(&mut self, obs: &mut dyn Observer) -> Result<(), SarlError> {
        let n = self.cfg.il.episodes;
        obs.stage("ORCA demonstrations", n as u64, 0);
        let g = self.cfg.gamma_bar();
        let policy = Policy::Orca {
            safety_space: self.cfg.il.safety_space,
        };
        let mut kept = 0usize;
        for d in 0..n {
            let mut rng = episode_rng(self.cfg.seed, SeedStream::Demo, d as u64);
            let ep = run_episode(&self.cfg.env, &policy, &mut rng)?;
            if ep.outcome != Outcome::Timeout {
                let stride = ep.humans * JOINT_DIM;
                let mut ret = 0.0;
                let mut values = vec![0.0; ep.steps()];
                for i in (0..ep.steps()).rev() {
                    ret = ep.rewards[i] + g * ret;
                    values[i] = ret;
                }
                for (i, v) in values.iter().enumerate() {
                    self.memory
                        .push(&ep.states[i * stride..(i + 1) * stride], *v as f32);
                }
                kept += ep.steps();
            }
            if (d + 1) % 50 == 0 || d + 1 == n {
                obs.tick((d + 1) as u64, &format!("{kept} transitions"));
            }
        }
        self.progress.demos_done = true;
        self.progress.demo_transitions = kept;
        obs.note(&format!("{n} ORCA demonstrations: {kept} transitions kept"));
        Ok(())
    }

    /// One imitation epoch over the memory in shuffled minibatches; mean MSE.
    fn il_epoch(&mut self, epoch: usize) -> Result<f64, SarlError> {
        let mut order: Vec<usize> = (0..self.memory.len()).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ (0x11 << 48) ^ epoch as u64);
        order.shuffle(&mut rng);
        let lr = self.cfg.il.learning_rate;
        let mut sum = 0.0;
        let mut k = 0usize;
        for chunk in order.chunks(self.cfg.optim.batch_size) {
            sum += self.update(chunk, lr)?;
            k += 1;
        }
        Ok(if k > 0 { sum / k as f64 } else { 0.0 })
    }

    /// One TD episode (exploration, memory update, minibatch updates): its outcome and the
    /// mean minibatch loss.
    fn rl_episode(&mut self, e: usize) -> Result<(Outcome, f64), SarlError> {
        let mut rng = episode_rng(self.cfg.seed, SeedStream::Train, e as u64);
        let policy = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: self.cfg.rl.epsilon(e),
        };
        let ep = run_episode(&self.cfg.env, &policy, &mut rng)?;
        if ep.outcome != Outcome::Timeout {
            let stride = ep.humans * JOINT_DIM;
            let steps = ep.steps();
            let next_values = if steps > 1 {
                self.target
                    .values(&ep.states[stride..], steps - 1, ep.humans)?
            } else {
                Vec::new()
            };
            let g = self.cfg.gamma_bar();
            for i in 0..steps {
                let v = if i + 1 == steps {
                    ep.rewards[i]
                } else {
                    ep.rewards[i] + g * f64::from(next_values[i])
                };
                self.memory
                    .push(&ep.states[i * stride..(i + 1) * stride], v as f32);
            }
        }
        let mut sum = 0.0;
        let n = self.cfg.rl.batches_per_episode;
        let len = self.memory.len();
        if len >= self.cfg.optim.batch_size {
            for _ in 0..n {
                let idx: Vec<usize> = (0..self.cfg.optim.batch_size)
                    .map(|_| rng.random_range(0..len))
                    .collect();
                sum += self.update(&idx, self.cfg.rl.learning_rate)?;
            }
        }
        Ok((ep.outcome, if n > 0 { sum / n as f64 } else { 0.0 }))
    }

    /// One SGD-with-momentum step on the memory rows `indices` (PyTorch's rule:
    /// `b ← μ·b + g`, `θ ← θ − lr·b`); the minibatch MSE before the step.
    fn update(&mut self, indices: &[usize], lr: f64) -> Result<f64, SarlError> {
        let (x, y) = self.memory.batch(indices);
        let vars = self.model.var_store().variables();
        for v in vars.values() {
            v.shallow_clone().zero_grad();
        }
        let pred = self.model.forward(&x);
        let loss = pred.mse_loss(&y, tch::Reduction::Mean);
        loss.backward();
        let mu = self.cfg.optim.momentum;
        tch::no_grad(|| {
            for (name, v) in &vars {
                let g = v.grad();
                if let Some(b) = self.momentum.get_mut(name) {
                    *b *= mu;
                    *b += &g;
                    let mut p = v.shallow_clone();
                    p -= &*b * lr;
                }
            }
        });
        Ok(loss.double_value(&[]))
    }

    /// Greedy validation on the validation stream; appends to the log.
    fn validate(&mut self, obs: &mut dyn Observer) -> Result<EvalStats, SarlError> {
        let policy = Policy::Sarl {
            net: &self.model,
            actions: &self.actions,
            lookahead: self.cfg.lookahead(),
            epsilon: 0.0,
        };
        let s = evaluate(
            &self.cfg.env,
            &policy,
            self.cfg.seed,
            SeedStream::Validation,
            self.cfg.run.eval_episodes,
            &mut |_| {},
        )?;
        self.progress.validation.push(ValPoint {
            episode: self.progress.rl_episodes_done,
            success_rate: s.success_rate,
            collision_rate: s.collision_rate,
            timeout_rate: s.timeout_rate,
        });
        let _ = obs;
        Ok(s)
    }
}

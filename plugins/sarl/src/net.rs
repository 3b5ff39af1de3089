//! The SARL value network (Chen et al. 2019, CrowdNav `sarl.ValueNetwork`) in tch.
//!
//! Input: a batch of `B` states, each the `N` joint states of the robot with every human
//! (`[B, N, 13]`, see [`crate::state`]). With `e_i = mlp1(s_i)` (ReLU after every layer):
//!
//! * pairwise embedding `h_i = mlp2(e_i)` (no ReLU after the last layer);
//! * global state `ē = mean_i e_i`; attention score `α_i = attention([e_i, ē])` (no final
//!   ReLU); weights `w = softmax(α)` over the humans, so `Σ_i w_i = 1`;
//! * crowd feature `c = Σ_i w_i h_i`;
//! * value `V = mlp3([self state, c])`, the self state being the first
//!   [`SELF_DIM`] entries of a joint state.
//!
//! The layer sizes are CrowdNav's defaults (see [`NetConfig::default`]): mlp1 13 → 150 → 100,
//! mlp2 100 → 100 → 50, attention 200 → 100 → 100 → 1 (with the global state), mlp3
//! 56 → 150 → 100 → 100 → 1: 96,502 parameters. The network is permutation-invariant in the
//! humans (and its attention weights permutation-equivariant), and accepts any `N ≥ 1`.
//! Initialisation is PyTorch's `nn.Linear` default (uniform in ±1/√fan_in), as in CrowdNav.

use crate::error::SarlError;
use crate::state::{JOINT_DIM, SELF_DIM};
use serde::{Deserialize, Serialize};
use std::path::Path;
use tch::{Device, Kind, Tensor, nn, nn::Module};

/// Hidden layer sizes. Defaults are CrowdNav's `sarl` section.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NetConfig {
    /// mlp1 (joint state → interaction embedding), ReLU after every layer. Default [150, 100].
    pub mlp1: Vec<usize>,
    /// mlp2 (embedding → pairwise feature). Default [100, 50].
    pub mlp2: Vec<usize>,
    /// attention ([e_i, mean e] → score); the last size must be 1. Default [100, 100, 1].
    pub attention: Vec<usize>,
    /// mlp3 (value head on [self state, pooled feature]); the last size must be 1.
    /// Default [150, 100, 100, 1].
    pub mlp3: Vec<usize>,
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            mlp1: vec![150, 100],
            mlp2: vec![100, 50],
            attention: vec![100, 100, 1],
            mlp3: vec![150, 100, 100, 1],
        }
    }
}

impl NetConfig {
    /// Checks the sizes; names the first offending field.
    pub fn validate(&self) -> Result<(), SarlError> {
        for (field, sizes) in [
            ("net.mlp1", &self.mlp1),
            ("net.mlp2", &self.mlp2),
            ("net.attention", &self.attention),
            ("net.mlp3", &self.mlp3),
        ] {
            if sizes.is_empty() || sizes.contains(&0) {
                return Err(SarlError::config(
                    field,
                    format!("needs at least one layer and no zero size, got {sizes:?}"),
                ));
            }
        }
        for (field, sizes) in [("net.attention", &self.attention), ("net.mlp3", &self.mlp3)] {
            if sizes.last() != Some(&1) {
                return Err(SarlError::config(
                    field,
                    format!("must end in 1 (a scalar), got {sizes:?}"),
                ));
            }
        }
        Ok(())
    }

    /// Number of trainable parameters this configuration implies.
    pub fn parameter_count(&self) -> usize {
        fn mlp(input: usize, sizes: &[usize]) -> usize {
            let mut n = 0;
            let mut i = input;
            for &o in sizes {
                n += i * o + o;
                i = o;
            }
            n
        }
        let e = self.mlp1.last().copied().unwrap_or(0);
        let f = self.mlp2.last().copied().unwrap_or(0);
        mlp(JOINT_DIM, &self.mlp1)
            + mlp(e, &self.mlp2)
            + mlp(2 * e, &self.attention)
            + mlp(SELF_DIM + f, &self.mlp3)
    }
}

/// A stack of linear layers with ReLU between them (and after the last when `last_relu`).
#[derive(Debug)]
struct Mlp {
    layers: Vec<nn::Linear>,
    last_relu: bool,
}

impl Mlp {
    fn new(p: nn::Path<'_>, input: usize, sizes: &[usize], last_relu: bool) -> Self {
        let mut layers = Vec::with_capacity(sizes.len());
        let mut i = input as i64;
        for (k, &o) in sizes.iter().enumerate() {
            // PyTorch's default for nn.Linear (CrowdNav's networks): weights and biases
            // uniform in ±1/√fan_in. (tch's default weight bound is √6 times larger.)
            let b = 1.0 / (i as f64).sqrt();
            let cfg = nn::LinearConfig {
                ws_init: nn::Init::Uniform { lo: -b, up: b },
                bs_init: Some(nn::Init::Uniform { lo: -b, up: b }),
                bias: true,
            };
            layers.push(nn::linear(&p / k, i, o as i64, cfg));
            i = o as i64;
        }
        Self { layers, last_relu }
    }

    fn forward(&self, x: &Tensor) -> Tensor {
        let n = self.layers.len();
        let mut h = x.shallow_clone();
        for (k, l) in self.layers.iter().enumerate() {
            h = l.forward(&h);
            if k + 1 < n || self.last_relu {
                h = h.relu();
            }
        }
        h
    }
}

/// The SARL value network with its own variable store.
#[derive(Debug)]
pub struct SarlNet {
    vs: nn::VarStore,
    config: NetConfig,
    mlp1: Mlp,
    mlp2: Mlp,
    attention: Mlp,
    mlp3: Mlp,
}

/// The network's outputs for a batch.
#[derive(Debug)]
pub struct Forward {
    /// `[B, 1]` state values.
    pub value: Tensor,
    /// `[B, N]` attention weights (each row sums to one).
    pub attention: Tensor,
}

impl SarlNet {
    /// A freshly initialised network (libtorch's default initialisation; seed with
    /// `tch::manual_seed` for reproducibility) on `device`.
    pub fn new(config: &NetConfig, device: Device) -> Result<Self, SarlError> {
        config.validate()?;
        let vs = nn::VarStore::new(device);
        let root = vs.root();
        let e = config.mlp1.last().copied().unwrap_or(1);
        let f = config.mlp2.last().copied().unwrap_or(1);
        let mlp1 = Mlp::new(&root / "mlp1", JOINT_DIM, &config.mlp1, true);
        let mlp2 = Mlp::new(&root / "mlp2", e, &config.mlp2, false);
        let attention = Mlp::new(&root / "attention", 2 * e, &config.attention, false);
        let mlp3 = Mlp::new(&root / "mlp3", SELF_DIM + f, &config.mlp3, false);
        Ok(Self {
            vs,
            config: config.clone(),
            mlp1,
            mlp2,
            attention,
            mlp3,
        })
    }

    /// A network initialised from `seed` alone (PyTorch's default bounds, drawn with ChaCha8
    /// layer by layer), independent of libtorch's global generator and of other threads.
    pub fn seeded(config: &NetConfig, seed: u64, device: Device) -> Result<Self, SarlError> {
        use rand::{Rng, SeedableRng};
        let net = Self::new(config, device)?;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let _guard = tch::no_grad_guard();
        for mlp in [&net.mlp1, &net.mlp2, &net.attention, &net.mlp3] {
            for l in &mlp.layers {
                let fan_in = l.ws.size()[1];
                let b = 1.0 / (fan_in as f64).sqrt();
                let mut fill = |t: &Tensor| -> Result<(), SarlError> {
                    let n = t.numel();
                    let v: Vec<f32> = (0..n).map(|_| rng.random_range(-b..b) as f32).collect();
                    let src = Tensor::from_slice(&v).reshape(t.size()).to_device(device);
                    t.shallow_clone().f_copy_(&src)?;
                    Ok(())
                };
                fill(&l.ws)?;
                if let Some(bs) = &l.bs {
                    fill(bs)?;
                }
            }
        }
        Ok(net)
    }

    /// The layer sizes.
    pub fn config(&self) -> &NetConfig {
        &self.config
    }

    /// The variable store (for optimisers and copying).
    pub fn var_store(&self) -> &nn::VarStore {
        &self.vs
    }

    /// Mutable variable store (loading weights).
    pub fn var_store_mut(&mut self) -> &mut nn::VarStore {
        &mut self.vs
    }

    /// Value and attention weights of a `[B, N, 13]` batch.
    pub fn forward_full(&self, states: &Tensor) -> Forward {
        let (b, n, d) = states.size3().unwrap_or((0, 0, 0));
        let flat = states.reshape([b * n, d]);
        let e = self.mlp1.forward(&flat);
        let e_dim = e.size()[1];
        let h = self.mlp2.forward(&e);
        let global = e
            .reshape([b, n, e_dim])
            .mean_dim(1, true, Kind::Float)
            .expand([b, n, e_dim], false)
            .reshape([b * n, e_dim]);
        let scores = self
            .attention
            .forward(&Tensor::cat(&[&e, &global], 1))
            .reshape([b, n]);
        let weights = scores.softmax(1, Kind::Float);
        let f_dim = h.size()[1];
        let pooled = (weights.unsqueeze(2) * h.reshape([b, n, f_dim])).sum_dim_intlist(
            1,
            false,
            Kind::Float,
        );
        let self_state = states.select(1, 0).narrow(1, 0, SELF_DIM as i64);
        let value = self.mlp3.forward(&Tensor::cat(&[&self_state, &pooled], 1));
        Forward {
            value,
            attention: weights,
        }
    }

    /// `[B, 1]` values of a `[B, N, 13]` batch.
    pub fn forward(&self, states: &Tensor) -> Tensor {
        self.forward_full(states).value
    }

    /// Values of `b` states of `n` humans given as a flat row-major `f32` slice
    /// (`b·n·13` numbers), without gradients.
    pub fn values(&self, flat: &[f32], b: usize, n: usize) -> Result<Vec<f32>, SarlError> {
        let _guard = tch::no_grad_guard();
        let x = Tensor::from_slice(flat)
            .reshape([b as i64, n as i64, JOINT_DIM as i64])
            .to_device(self.vs.device());
        let v = self.forward(&x).reshape([-1]).to_device(Device::Cpu);
        Ok(Vec::<f32>::try_from(&v)?)
    }

    /// Copies every weight of `other` (same architecture) into this network.
    pub fn copy_from(&mut self, other: &SarlNet) -> Result<(), SarlError> {
        self.vs.copy(&other.vs)?;
        Ok(())
    }

    /// Saves the weights as safetensors.
    pub fn save(&self, path: &Path) -> Result<(), SarlError> {
        let tmp = path.with_extension("tmp.safetensors");
        self.vs.save(&tmp).map_err(|e| SarlError::Weights {
            path: tmp.clone(),
            message: e.to_string(),
        })?;
        std::fs::rename(&tmp, path).map_err(|e| SarlError::io(path, e))
    }

    /// Loads weights saved by [`SarlNet::save`] (every tensor must be present with its shape).
    pub fn load(&mut self, path: &Path) -> Result<(), SarlError> {
        if !path.is_file() {
            return Err(SarlError::Weights {
                path: path.to_path_buf(),
                message: "file not found".into(),
            });
        }
        self.vs.load(path).map_err(|e| SarlError::Weights {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }
}

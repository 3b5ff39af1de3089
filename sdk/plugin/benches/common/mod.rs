//! What the plugin benchmarks share: where the plugin libraries are, the scene they are timed
//! on and paired timing. Each benchmark uses part of it.
#![allow(dead_code)]

use human2nav_core::{AgentState, Limits};
use std::path::PathBuf;
use std::time::Instant;

/// Poses per trajectory.
pub const HORIZON: usize = 32;

/// A cdylib of the benchmarks' dev-dependencies: next to the benchmark (cargo builds them into
/// `deps/`), else in the profile directory above it.
pub fn library(name: &str) -> PathBuf {
    let deps = std::env::current_exe()
        .ok()
        .and_then(|exe| exe.parent().map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from("target/release/deps"));
    let here = deps.join(name);
    if human2nav_plugin::locate::resolve_library_path(&here).is_ok() {
        return here;
    }
    deps.parent().unwrap_or(&deps).join(name)
}

/// Eight pedestrians around a point 2 m ahead.
pub fn agents() -> Vec<AgentState> {
    (0..8)
        .map(|j| {
            let a = j as f64 * 0.785;
            AgentState {
                id: j,
                position: [2.0 + 1.5 * a.cos(), 1.5 * a.sin()],
                velocity: [-0.8 * a.cos(), 0.6 * a.sin()],
                radius: 0.3,
                history: vec![[0.0, 0.0]; 8],
            }
        })
        .collect()
}

/// `batch` gently bending trajectories of [`HORIZON`] poses, flat `[batch, HORIZON, 3]`.
pub fn trajectories(batch: usize) -> Vec<f64> {
    let mut data = Vec::with_capacity(batch * HORIZON * 3);
    for b in 0..batch {
        let bend = (b as f64 - batch as f64 / 2.0) * 0.02;
        for k in 0..HORIZON {
            let s = k as f64 * 0.1;
            data.extend_from_slice(&[1.2 * s, bend * s * s, 2.0 * bend * s]);
        }
    }
    data
}

/// The limits the constraint benchmarks evaluate against.
pub fn limits() -> Limits {
    Limits {
        v_max: 1.2,
        v_reverse_max: 0.4,
        a_max: 1.0,
        omega_max: 1.5,
        kappa_max: None,
        lateral_speed_max: 0.05,
        coupled: None,
    }
}

/// Times of `n` alternating calls of `a` then `b`, µs, each sorted: `a`'s, `b`'s and the
/// per-pair differences `b − a`.
pub struct Paired {
    pub a: Vec<f64>,
    pub b: Vec<f64>,
    pub diff: Vec<f64>,
}

impl Paired {
    pub fn run(n: usize, mut a: impl FnMut(), mut b: impl FnMut()) -> Self {
        let (mut ta, mut tb, mut d) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..n {
            let t0 = Instant::now();
            a();
            let t1 = Instant::now();
            b();
            let t2 = Instant::now();
            let (x, y) = ((t1 - t0).as_secs_f64() * 1e6, (t2 - t1).as_secs_f64() * 1e6);
            ta.push(x);
            tb.push(y);
            d.push(y - x);
        }
        for v in [&mut ta, &mut tb, &mut d] {
            v.sort_by(f64::total_cmp);
        }
        Self {
            a: ta,
            b: tb,
            diff: d,
        }
    }

    /// The value at `num/den` of a sorted sample (`1/2`: the median).
    pub fn at(v: &[f64], num: usize, den: usize) -> f64 {
        v[v.len() * num / den]
    }
}

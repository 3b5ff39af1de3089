//! Latency: percentiles of planning-call wall times ([`measure_latency`]) and [`TimedModel`],
//! which splits them into time inside the flow network and everything else.

use human2nav_core::flow::{FlowCondition, FlowError, FlowModel, FlowQuery};
use human2nav_core::{Observation, PlanError, Planner};
use serde::Serialize;
use std::sync::{Arc, Mutex};
use std::time::Instant;

/// Percentiles of planning-call wall times, milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct LatencyStats {
    /// Timed calls.
    pub calls: usize,
    /// Median wall time (ms).
    pub p50_ms: f64,
    /// 95th percentile wall time (ms).
    pub p95_ms: f64,
    /// Mean wall time (ms).
    pub mean_ms: f64,
    /// Slowest call (ms).
    pub max_ms: f64,
}

impl LatencyStats {
    /// Statistics of a set of durations in milliseconds (nearest-rank percentiles: the value
    /// at index `ceil(q·n) − 1` of the sorted list).
    pub fn of(ms: &[f64]) -> Self {
        let mut v: Vec<f64> = ms.iter().copied().filter(|x| x.is_finite()).collect();
        if v.is_empty() {
            return Self {
                calls: 0,
                p50_ms: f64::NAN,
                p95_ms: f64::NAN,
                mean_ms: f64::NAN,
                max_ms: f64::NAN,
            };
        }
        v.sort_by(f64::total_cmp);
        let rank = |q: f64| {
            let i = ((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
            v[i]
        };
        Self {
            calls: v.len(),
            p50_ms: rank(0.5),
            p95_ms: rank(0.95),
            mean_ms: v.iter().sum::<f64>() / v.len() as f64,
            max_ms: v[v.len() - 1],
        }
    }
}

/// Wall time of `repeats` planning calls cycling through `observations` (after `warmup`
/// untimed calls). The planner is reset before every call, so each call is a cold single step
/// (no warm start; a new observation also misses the model's condition cache, as in closed
/// loop). `on_call` runs after every timed call (for a progress bar).
pub fn measure_latency<P: Planner + ?Sized>(
    planner: &mut P,
    observations: &[Observation],
    warmup: usize,
    repeats: usize,
    mut on_call: impl FnMut(),
) -> Result<LatencyStats, PlanError> {
    if observations.is_empty() {
        return Ok(LatencyStats::of(&[]));
    }
    for obs in observations.iter().cycle().take(warmup) {
        planner.reset();
        planner.plan(obs)?;
    }
    let mut ms = Vec::with_capacity(repeats);
    for obs in observations.iter().cycle().take(repeats) {
        planner.reset();
        let start = Instant::now();
        let plan = planner.plan(obs)?;
        ms.push(start.elapsed().as_secs_f64() * 1e3);
        std::hint::black_box(plan);
        on_call();
    }
    Ok(LatencyStats::of(&ms))
}

/// Calls and wall time spent inside a flow model, accumulated by [`TimedModel`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FlowCallStats {
    /// Calls of [`FlowModel::velocity`].
    pub velocity_calls: u64,
    /// Total time inside [`FlowModel::velocity`] (s).
    pub velocity_s: f64,
    /// Calls of [`FlowModel::velocity_vjp`].
    pub vjp_calls: u64,
    /// Total time inside [`FlowModel::velocity_vjp`] (s).
    pub vjp_s: f64,
    /// Trajectories passed through the network by velocity calls.
    pub velocity_rows: u64,
    /// Trajectories passed through the network by VJP calls.
    pub vjp_rows: u64,
}

impl FlowCallStats {
    /// The counts accumulated since `earlier`.
    pub fn since(&self, earlier: &Self) -> Self {
        Self {
            velocity_calls: self.velocity_calls - earlier.velocity_calls,
            velocity_s: self.velocity_s - earlier.velocity_s,
            vjp_calls: self.vjp_calls - earlier.vjp_calls,
            vjp_s: self.vjp_s - earlier.vjp_s,
            velocity_rows: self.velocity_rows - earlier.velocity_rows,
            vjp_rows: self.vjp_rows - earlier.vjp_rows,
        }
    }

    /// Floating-point operations of the network's convolutions and linear layers in these calls
    /// (2 per multiply-accumulate): `unet` per trajectory forward, twice that for a VJP (the
    /// forward pass and the gradient of its input, which is the transposed products, no weight
    /// gradients). The condition encoding and FiLM layers are not included (see
    /// [`crate::net::Complexity`]: under 1 % of a planning call). This is the architecture's
    /// count, what libtorch computes; the native backend counts what it did
    /// ([`crate::NativeCfm::macs`]: it reuses kept forward passes and skips empty crowd cells).
    pub fn network_flops(&self, unet_macs_per_trajectory: u64) -> f64 {
        let f = 2.0 * unet_macs_per_trajectory as f64;
        self.velocity_rows as f64 * f + self.vjp_rows as f64 * 2.0 * f
    }
}

/// A flow model that times every call of the model it wraps (a profiler for the planner:
/// the planning time minus the time recorded here is sampling arithmetic, Φ, the adjoint
/// pass, selection and rasterisation). The counters are shared through [`Self::stats`], so they
/// can be read while a planner owns the model.
#[derive(Debug)]
pub struct TimedModel<M> {
    pub(super) inner: M,
    stats: Arc<Mutex<FlowCallStats>>,
}

impl<M> TimedModel<M> {
    /// Wraps `inner` with zeroed counters.
    pub fn new(inner: M) -> Self {
        Self {
            inner,
            stats: Arc::new(Mutex::new(FlowCallStats::default())),
        }
    }

    /// A handle on the counters.
    pub fn stats(&self) -> Arc<Mutex<FlowCallStats>> {
        Arc::clone(&self.stats)
    }

    /// The model it times.
    pub fn inner(&self) -> &M {
        &self.inner
    }

    fn record(&self, vjp: bool, rows: u64, seconds: f64) {
        if let Ok(mut s) = self.stats.lock() {
            if vjp {
                s.vjp_calls += 1;
                s.vjp_s += seconds;
                s.vjp_rows += rows;
            } else {
                s.velocity_calls += 1;
                s.velocity_s += seconds;
                s.velocity_rows += rows;
            }
        }
    }
}

impl<M: FlowModel> FlowModel for TimedModel<M> {
    fn horizon(&self) -> usize {
        self.inner.horizon()
    }

    fn source_std(&self) -> [f64; 3] {
        self.inner.source_std()
    }

    fn velocity(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        out: &mut [f64],
    ) -> Result<(), FlowError> {
        let start = Instant::now();
        let r = self.inner.velocity(x, t, cond, out);
        let rows = (x.len() / (3 * self.inner.horizon()).max(1)) as u64;
        self.record(false, rows, start.elapsed().as_secs_f64());
        r
    }

    fn velocity_vjp(
        &self,
        x: &[f64],
        t: f64,
        cond: &FlowCondition,
        cotangent: &[f64],
        out: &mut [f64],
        vjp: &mut [f64],
    ) -> Result<(), FlowError> {
        let start = Instant::now();
        let r = self.inner.velocity_vjp(x, t, cond, cotangent, out, vjp);
        let rows = (x.len() / (3 * self.inner.horizon()).max(1)) as u64;
        self.record(true, rows, start.elapsed().as_secs_f64());
        r
    }

    /// Counted as one call of all the groups' rows.
    fn velocity_batch(&self, queries: &[FlowQuery<'_>], out: &mut [f64]) -> Result<(), FlowError> {
        let start = Instant::now();
        let r = self.inner.velocity_batch(queries, out);
        let values: usize = queries.iter().map(|q| q.x.len()).sum();
        let rows = (values / (3 * self.inner.horizon()).max(1)) as u64;
        self.record(false, rows, start.elapsed().as_secs_f64());
        r
    }

    fn network_id(&self) -> Option<usize> {
        self.inner.network_id()
    }
}

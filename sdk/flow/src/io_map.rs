//! The closed-form maps between core's metric poses and velocities (flat `[K, T, 3]`) and the
//! network's standardised arrays, shared by both implementations of the network. The network
//! arrays are addressed through a closure over `(trajectory b, channel c, waypoint j)`, so
//! each backend keeps its own layout (libtorch `[K, C, T]`, the native path `[C, K, T]`).

use human2nav_core::flow::FlowError;

/// The number of trajectories in flat poses `x` of `horizon` waypoints, or a shape error.
pub(crate) fn batch_of(len: usize, horizon: usize) -> Result<usize, FlowError> {
    if len == 0 || len % (3 * horizon) != 0 {
        return Err(FlowError::Shape(format!(
            "x has {len} values, not a positive multiple of T·3 = {}",
            3 * horizon
        )));
    }
    Ok(len / (3 * horizon))
}

/// A shape error unless the array `name` has `want` values.
pub(crate) fn check_len(name: &str, got: usize, want: usize) -> Result<(), FlowError> {
    if got != want {
        return Err(FlowError::Shape(format!(
            "{name} has {got} values, expected {want}"
        )));
    }
    Ok(())
}

/// Calls `write(b, c, j, value)` with the network features of metric poses `x`: for waypoint
/// `j` of trajectory `b`, `x/s, y/s, cos θ, sin θ, (j + 1)/T` (`s` = `position_scale`).
pub(crate) fn for_each_feature(
    x: &[f64],
    horizon: usize,
    position_scale: f64,
    mut write: impl FnMut(usize, usize, usize, f64),
) {
    let inv_s = 1.0 / position_scale;
    for (b, traj) in x.chunks_exact(3 * horizon).enumerate() {
        for (j, p) in traj.chunks_exact(3).enumerate() {
            let (sin, cos) = p[2].sin_cos();
            write(b, 0, j, p[0] * inv_s);
            write(b, 1, j, p[1] * inv_s);
            write(b, 2, j, cos);
            write(b, 3, j, sin);
            write(b, 4, j, (j + 1) as f64 / horizon as f64);
        }
    }
}

/// Metric velocities `out[b, j, c] = net(b, c, j)·out_scale[c]` from the network's standardised
/// output; a non-finite value is an error.
pub(crate) fn write_velocity(
    out: &mut [f64],
    horizon: usize,
    out_scale: [f64; 3],
    net: impl Fn(usize, usize, usize) -> f64,
) -> Result<(), FlowError> {
    for (b, traj) in out.chunks_exact_mut(3 * horizon).enumerate() {
        for j in 0..horizon {
            for c in 0..3 {
                traj[3 * j + c] = net(b, c, j) * out_scale[c];
            }
        }
    }
    if out.iter().any(|v| !v.is_finite()) {
        return Err(FlowError::NonFinite);
    }
    Ok(())
}

/// Calls `write(b, c, j, value)` with the cotangent of the standardised output for a cotangent
/// of the metric velocities: `cotangent[b, j, c]·out_scale[c]`.
pub(crate) fn for_each_output_cotangent(
    cotangent: &[f64],
    horizon: usize,
    out_scale: [f64; 3],
    mut write: impl FnMut(usize, usize, usize, f64),
) {
    for (b, traj) in cotangent.chunks_exact(3 * horizon).enumerate() {
        for j in 0..horizon {
            for c in 0..3 {
                write(b, c, j, traj[3 * j + c] * out_scale[c]);
            }
        }
    }
}

/// The pull-back of the gradient of the features (`grad(b, c, j)`) to the metric poses `x`:
/// `(g_x/s, g_y/s, −sin θ·g_cos + cos θ·g_sin)` per waypoint, into `vjp`; a non-finite value
/// is an error.
pub(crate) fn pull_back_features(
    x: &[f64],
    horizon: usize,
    position_scale: f64,
    grad: impl Fn(usize, usize, usize) -> f64,
    vjp: &mut [f64],
) -> Result<(), FlowError> {
    let inv_s = 1.0 / position_scale;
    let rows = vjp
        .chunks_exact_mut(3 * horizon)
        .zip(x.chunks_exact(3 * horizon));
    for (b, (o, xt)) in rows.enumerate() {
        for j in 0..horizon {
            let (sin, cos) = xt[3 * j + 2].sin_cos();
            o[3 * j] = grad(b, 0, j) * inv_s;
            o[3 * j + 1] = grad(b, 1, j) * inv_s;
            o[3 * j + 2] = -sin * grad(b, 2, j) + cos * grad(b, 3, j);
        }
    }
    if vjp.iter().any(|v| !v.is_finite()) {
        return Err(FlowError::NonFinite);
    }
    Ok(())
}

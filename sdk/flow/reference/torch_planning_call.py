"""A plain PyTorch re-implementation of the network work of one planning call.

What `human2nav plan --bench` times with the native backend, written as a researcher's
prototype would be (eager torch ops, autograd for the adjoint), on the shipped model
(`models/human2nav-cfm`: the network of `torch_train_step.py` with its crowd pathway):

* the condition: the planner's BEV raster with its velocity channels divided by the speed
  scale, goal and ego velocity divided by their scales (`normalise_condition`), the crowd points
  (`crowd_points`: the occupied cells nearest the ego, at most `[net.crowd] points`), the
  condition embedding once per call;
* raw sampling: K source samples integrated in N Lie-group Euler steps,
  `x <- x exp(dt v(x, i dt))`, one network pass of K rows a step (features
  `(x/s, y/s, cos th, sin th, (i + 1)/T)`, output times `(s std_x, s std_y, std_th)`);
* the guided call's network work: the raw sampling, then M iterations of Algorithm 1 on the G
  shortlisted samples: a rollout of N steps with the controls `u` as autograd leaves, the
  backward pass of a cost of the final poses through it (N vector-Jacobian products), and the
  control update. The cost here is the robot's speed excess over 1 m/s, squared; the Rust call
  computes Φ and its gradient and the last-step correction besides, which this leaves out.

Modes (run from the workspace root with the torch virtualenv's python3):

    cargo run --release -p human2nav-flow --example planning_reference -- \\
        models/human2nav-cfm out/data/episodes-interaction-val.json \\
        target/torch_reference/planning.safetensors
    python3 sdk/flow/reference/torch_planning_call.py --check target/torch_reference/planning.safetensors
    python3 sdk/flow/reference/torch_planning_call.py --bench target/torch_reference/planning.safetensors

`--check` samples from the Rust source samples under the Rust conditions and reports the
largest difference to the native backend's samples. `--bench` prints the p50 and mean
milliseconds of the raw and the guided call over the file's windows (one thread by default).
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
import tomllib
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from torch_train_step import (  # noqa: E402
    AHEAD_FRACTION,
    CondUnet1d,
    read_safetensors,
    se2_compose,
    se2_exp,
)


class Model:
    """The network of a model folder with its card's normalisation."""

    def __init__(self, folder: Path):
        card = tomllib.loads((folder / "model.toml").read_text())
        self.net_cfg = card["net"]
        self.norm = card["normalisation"]
        self.net = CondUnet1d(self.net_cfg)
        weights = read_safetensors(folder / card["weights"])
        self.net.load_state_dict({k: v.float() for k, v in weights.items()}, strict=True)
        self.net.eval()
        s = self.norm["position_scale"]
        std = self.norm["velocity_std"]
        self.s = s
        self.out_scale = torch.tensor([s * std[0], s * std[1], std[2]], dtype=torch.float64)
        self.horizon = self.net_cfg["horizon"]

    def condition(self, bev, goal, velocity):
        """The condition embedding `[1, D]` and crowd points `[1, N, 5]` of one raster."""
        n = self.norm
        b = bev.clone().float()
        b[1:] = b[1:] / n["speed_scale"]
        g = goal if n["goal_conditioned"] else [0.0, 0.0]
        v = velocity if n["velocity_conditioned"] else [0.0, 0.0]
        gv = torch.tensor(
            [[g[0] / n["goal_scale"], g[1] / n["goal_scale"],
              v[0] / n["speed_scale"], v[1] / n["speed_scale"]]],
            dtype=torch.float32,
        )
        with torch.no_grad():
            emb = self.net.encode_condition(b.unsqueeze(0), gv)
        return emb, self.crowd_points(bev)

    def crowd_points(self, bev):
        """`crowd_points`: the occupied cells nearest the ego (ties by cell index), each as
        `(x/s, y/s, v_x/s, v_y/s, 1)`, the rest zero."""
        crowd = self.net_cfg["crowd"]
        cells, res = self.net_cfg["bev_cells"], crowd["cell"]
        extent = cells * res
        ahead, half = AHEAD_FRACTION * extent, 0.5 * extent
        occ = bev[0].flatten()
        found = []
        for i in torch.nonzero(occ > 0.5).flatten().tolist():
            r, c = divmod(i, cells)
            x, y = ahead - (r + 0.5) * res, half - (c + 0.5) * res
            found.append((math.hypot(x, y), i, x, y))
        found.sort()
        pts = torch.zeros(1, crowd["points"], 5)
        inv = 1.0 / self.s
        vx, vy = bev[1].flatten(), bev[2].flatten()
        for row, (_, i, x, y) in enumerate(found[: crowd["points"]]):
            pts[0, row] = torch.tensor(
                [x * inv, y * inv, float(vx[i]) * inv, float(vy[i]) * inv, 1.0]
            )
        return pts

    def velocity(self, x, t, emb, points):
        """Metric body velocities `[K, T, 3]` (float64) of metric poses `x` at flow time `t`."""
        k, h = x.shape[0], x.shape[1]
        j = (torch.arange(h, dtype=torch.float64) + 1.0) / h
        feats = torch.stack(
            [x[..., 0] / self.s, x[..., 1] / self.s, torch.cos(x[..., 2]), torch.sin(x[..., 2]),
             j.expand(k, h)],
            1,
        ).float()
        tt = torch.full((k,), float(t))
        out = self.net(feats, tt, emb.expand(k, -1), points)
        return out.permute(0, 2, 1).double() * self.out_scale


def sample(model, x0, emb, points, steps):
    """Raw sampling: `steps` Euler steps from `x0` (`[K, T, 3]`), no autograd."""
    x, dt = x0.clone(), 1.0 / steps
    with torch.no_grad():
        for i in range(steps):
            x = se2_compose(x, se2_exp(dt * model.velocity(x, i * dt, emb, points)))
    return x


def speed_excess(x, dt=0.1, v_max=1.0):
    """The cost the guided rollout descends: squared speed over `v_max` along each path."""
    start = torch.zeros_like(x[:, :1])
    pts = torch.cat([start, x], 1)[..., :2]
    speed = (pts[:, 1:] - pts[:, :-1]).norm(dim=-1) / dt
    return torch.relu(speed - v_max).square().sum()


def guided(model, x0, emb, points, steps, iterations, shortlist, lr=0.1):
    """The raw sampling, then `iterations` of Algorithm 1's rollout, adjoint and update on the
    first `shortlist` samples."""
    raw = sample(model, x0, emb, points, steps)
    sub = x0[:shortlist]
    u = torch.zeros(steps, *sub.shape, dtype=torch.float64, requires_grad=True)
    dt = 1.0 / steps
    for _ in range(iterations):
        x = sub
        for i in range(steps):
            v = model.velocity(x, i * dt, emb, points) + u[i]
            x = se2_compose(x, se2_exp(dt * v))
        (g,) = torch.autograd.grad(speed_excess(x), u)
        with torch.no_grad():
            u -= lr * g
    return raw, x.detach()


def load(path: Path):
    f = read_safetensors(path)
    meta = {k: int(v.item()) for k, v in f.items() if k.startswith("settings.")}
    return f, meta


def check(model: Model, path: Path):
    f, meta = load(path)
    steps = meta["settings.steps_n"]
    worst = 0.0
    for w in range(f["x0"].shape[0]):
        emb, points = model.condition(f["bev"][w], f["goal"][w].tolist(), f["velocity"][w].tolist())
        with torch.no_grad():
            v = model.velocity(f["x0"][w], 0.0, emb, points)
        first = float((v - f["v0"][w]).abs().max() / f["v0"][w].abs().max())
        x = sample(model, f["x0"][w], emb, points, steps)
        diff = (x - f["x1"][w]).abs()
        diff[..., 2] = torch.remainder(diff[..., 2] + math.pi, 2 * math.pi) - math.pi
        worst = max(worst, float(diff.abs().max()))
        print(f"window {w}: {int(points[0, :, 4].sum())} crowd points; first velocity: relative "
              f"difference {first:.2e}; samples after {steps} steps: largest difference "
              f"{float(diff.abs().max()):.2e}")
    print(f"largest difference to the native samples over {f['x0'].shape[0]} windows: {worst:.2e}")
    if worst > 1e-3:
        raise SystemExit("the PyTorch call does not compute what the native one does")


def bench(model: Model, path: Path, calls: int, warmup: int, threads: int):
    torch.set_num_threads(threads)
    f, meta = load(path)
    steps, m, g = meta["settings.steps_n"], meta["settings.iterations_m"], meta["settings.guided"]
    windows = f["x0"].shape[0]
    k = f["x0"].shape[1]
    conds = [(f["bev"][w], f["goal"][w].tolist(), f["velocity"][w].tolist()) for w in range(windows)]

    def raw_call(w):
        emb, points = model.condition(*conds[w])
        sample(model, f["x0"][w], emb, points, steps)

    def guided_call(w):
        emb, points = model.condition(*conds[w])
        guided(model, f["x0"][w], emb, points, steps, m, g)

    print(f"PyTorch {torch.__version__}, {threads} thread(s), {windows} windows, K = {k}, "
          f"N = {steps}, guided: M = {m} on {g} samples")
    for name, call in [("raw", raw_call), ("guided", guided_call)]:
        for i in range(warmup):
            call(i % windows)
        ms = []
        for i in range(calls):
            start = time.perf_counter()
            call(i % windows)
            ms.append((time.perf_counter() - start) * 1e3)
        print(f"{name}: p50 {statistics.median(ms):.2f} ms, mean {statistics.fmean(ms):.2f} ms "
              f"over {calls} calls")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", type=Path, default=Path("models/human2nav-cfm"))
    ap.add_argument("--check", type=Path)
    ap.add_argument("--bench", type=Path)
    ap.add_argument("--calls", type=int, default=100)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    model = Model(args.model)
    if args.check:
        check(model, args.check)
    if args.bench:
        bench(model, args.bench, args.calls, args.warmup, args.threads)
    if not (args.check or args.bench):
        ap.error("give --check FILE or --bench FILE")


if __name__ == "__main__":
    main()

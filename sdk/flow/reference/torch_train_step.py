"""A plain PyTorch re-implementation of one training step of the Rust trainer.

The Rust trainer is `sdk/flow/src/train.rs` (`Trainer::train_step`) with the network
`CondUnet1d` of `sdk/flow/src/net.rs`. This file does the same step at the settings of
`sdk/configs/train.toml` (mirror and path_sigma off, as shipped):

* read the tuple cache (`out/data/cache`, format in `sdk/data/src/cache.rs`) and draw the BEV
  rasters once at load time, as `TupleCache::load` does;
* build a batch: indices from a per-epoch random permutation, the BEV stack with its velocity
  channels divided by the speed scale, goal and ego velocity divided by their scales, flow
  times `t = s(1 - u)`, `u ~ Beta(alpha, beta)`, unit-normal source twists `x0 = exp(xi0)`, the
  SE(2) geodesic point `x_t = x0 exp(t xi)` with `xi = log(x0^-1 x1)` (Eq. 3/4), features
  `(x, y, cos th, sin th, (i + 1)/T)` and the target `xi / velocity_std`;
* forward, MSE loss, backward, gradient-norm clipping, AdamW with linear warm-up and cosine
  decay, and the EMA of the weights.

Modes (run from the workspace root with the torch virtualenv's python3):

    python3 sdk/flow/reference/torch_train_step.py --bench [--steps 30] [--warmup 5] [--threads 1]
    python3 sdk/flow/reference/torch_train_step.py \
        --check target/torch_reference/rust_forward.safetensors

`--bench` times training steps (batch building included) and prints ms per step; `--check`
compares this network and batch building with the Rust ones on the batch written by
`cargo run --release -p human2nav-flow --example torch_reference` (see README.md).
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import statistics
import struct
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

# --------------------------------------------------------------------------------------------
# Data: the tuple cache and the BEV raster (sdk/data/src/cache.rs, sdk/core/src/bev.rs)
# --------------------------------------------------------------------------------------------

AHEAD_FRACTION = 0.75


def read_safetensors(path: Path) -> dict[str, torch.Tensor]:
    """Every tensor of a safetensors file (8-byte header length, JSON header, raw data)."""
    dtypes = {"F32": np.float32, "F64": np.float64, "I64": np.int64, "I32": np.int32}
    raw = Path(path).read_bytes()
    (n,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + n])
    out = {}
    for name, info in header.items():
        if name == "__metadata__":
            continue
        a, b = info["data_offsets"]
        dtype = np.dtype(dtypes[info["dtype"]])
        arr = np.frombuffer(raw, dtype=dtype, count=(b - a) // dtype.itemsize, offset=8 + n + a)
        out[name] = torch.from_numpy(arr.reshape(info["shape"]).copy())
    return out


def rasterize(rec, agents, n_records, cells, res):
    """Dense `[N, 3, H, W]` rasters of the agents (`[M, 5]`: x, y, vx, vy, radius in the ego
    frame, `rec` their record), vectorised over all agents: a cell is written by the agent
    whose centre is nearest among those whose disc holds the cell centre or whose centre lies
    in the cell, ties to the earlier agent (as `rasterize_agents`)."""
    out = np.zeros((n_records, 3, cells, cells), np.float32)
    extent = cells * res
    ahead = AHEAD_FRACTION * extent
    behind = extent - ahead
    half = 0.5 * extent
    a64 = agents.astype(np.float64)
    px, py, r = a64[:, 0], a64[:, 1], a64[:, 4]
    rr = np.maximum(r, res)
    ok = np.isfinite(a64).all(1) & (r >= 0)
    ok &= (px < ahead + rr) & (px > -behind - rr) & (np.abs(py) < half + rr)
    row_lo = np.maximum(np.floor((ahead - px - r) / res), 0)
    row_hi = np.minimum(np.floor((ahead - px + r) / res), cells - 1)
    col_lo = np.maximum(np.floor((half - py - r) / res), 0)
    col_hi = np.minimum(np.floor((half - py + r) / res), cells - 1)
    ok &= (row_hi >= 0) & (col_hi >= 0)
    keep = np.nonzero(ok)[0]
    span = 1 + int(max(np.max(row_hi[keep] - row_lo[keep], initial=0),
                       np.max(col_hi[keep] - col_lo[keep], initial=0)))
    rows_l, cols_l, keys_l, d2_l, who_l = [], [], [], [], []
    for dr in range(span):
        for dc in range(span):
            row = row_lo[keep] + dr
            col = col_lo[keep] + dc
            valid = (row <= row_hi[keep]) & (col <= col_hi[keep])
            cx = ahead - (row + 0.5) * res
            cy = half - (col + 0.5) * res
            d2 = (cx - px[keep]) ** 2 + (cy - py[keep]) ** 2
            valid &= d2 <= r[keep] * r[keep]
            rows_l.append(row[valid]), cols_l.append(col[valid])
            d2_l.append(d2[valid]), who_l.append(keep[valid])
    # The cell holding the centre.
    fr = (ahead - px[keep]) / res
    fc = (half - py[keep]) / res
    inside = (fr >= 0) & (fr < cells) & (fc >= 0) & (fc < cells)
    row = np.floor(fr[inside])
    col = np.floor(fc[inside])
    w = keep[inside]
    d2 = (ahead - (row + 0.5) * res - px[w]) ** 2 + (half - (col + 0.5) * res - py[w]) ** 2
    rows_l.append(row), cols_l.append(col), d2_l.append(d2), who_l.append(w)
    row = np.concatenate(rows_l).astype(np.int64)
    col = np.concatenate(cols_l).astype(np.int64)
    d2 = np.concatenate(d2_l)
    who = np.concatenate(who_l)
    key = (rec[who] * cells + row) * cells + col
    order = np.lexsort((who, d2, key))
    key, who = key[order], who[order]
    first = np.ones(len(key), bool)
    first[1:] = key[1:] != key[:-1]
    key, who = key[first], who[first]
    i, rc = np.divmod(key, cells * cells)
    rr_, cc_ = np.divmod(rc, cells)
    out[i, 0, rr_, cc_] = 1.0
    out[i, 1, rr_, cc_] = agents[who, 2]
    out[i, 2, rr_, cc_] = agents[who, 3]
    return out


@dataclass
class Tuples:
    bev: torch.Tensor  # [N, 3, H, W] float32
    goal: torch.Tensor  # [N, 2] float64
    velocity: torch.Tensor  # [N, 2] float64
    future: torch.Tensor  # [N, T, 3] float64


def load_split(cache_dir: Path, split: str) -> Tuples:
    """The dense tuples of one split of the cache, in file order."""
    manifest = json.loads((cache_dir / "manifest.json").read_text())
    raw = (cache_dir / f"{split}.bin").read_bytes()
    assert raw[:8] == b"H2NTUPL1", "not a human2nav tuple file"
    version, horizon, count = struct.unpack_from("<IIQ", raw, 8)
    assert version == 1 and horizon == manifest["horizon"]
    words = np.frombuffer(raw, "<f4")
    halves = np.frombuffer(raw, "<u2")
    fixed = 8 + 4 * (4 + 3 * horizon)
    offsets = np.empty(count, np.int64)
    at = 24
    for i in range(count):
        offsets[i] = at
        at += fixed + 20 * struct.unpack_from("<H", raw, at + 4)[0]
    assert at == len(raw), "trailing bytes"
    n_agents = halves[(offsets + 4) // 2].astype(np.int64)
    head = words[offsets[:, None] // 4 + 2 + np.arange(4 + 3 * horizon)]
    first = offsets // 4 + 2 + 4 + 3 * horizon
    starts = np.repeat(first, n_agents)
    within = np.arange(n_agents.sum()) - np.repeat(np.cumsum(n_agents) - n_agents, n_agents)
    agents = words[(starts + 5 * within)[:, None] + np.arange(5)]
    rec = np.repeat(np.arange(count), n_agents)
    bev = rasterize(rec, agents, count, manifest["bev"]["cells"], manifest["bev"]["resolution"])
    head = torch.from_numpy(head.astype(np.float64))
    return Tuples(
        bev=torch.from_numpy(bev),
        goal=head[:, 0:2].contiguous(),
        velocity=head[:, 2:4].contiguous(),
        future=head[:, 4:].reshape(count, horizon, 3).contiguous(),
    )


# --------------------------------------------------------------------------------------------
# SE(2) (sdk/core/src/se2.rs), batched over leading dimensions, poses and twists as [..., 3]
# --------------------------------------------------------------------------------------------

SMALL_ANGLE = 1e-6


def wrap(a):
    r = torch.fmod(a + math.pi, 2 * math.pi)
    r = torch.where(r < 0, r + 2 * math.pi, r) - math.pi
    r = torch.where(r <= -math.pi, r + 2 * math.pi, r)
    return torch.where((a > -math.pi) & (a <= math.pi), a, r)


def se2_exp(xi):
    vx, vy, w = xi.unbind(-1)
    small = w.abs() < SMALL_ANGLE
    safe = torch.where(small, torch.ones_like(w), w)
    h = torch.sin(0.5 * safe)
    a = torch.where(small, 1 - w * w / 6, torch.sin(safe) / safe)
    b = torch.where(small, w / 2 - w * w * w / 24, 2 * h * h / safe)
    return torch.stack([a * vx - b * vy, b * vx + a * vy, wrap(w)], -1)


def se2_log(p):
    x, y, th = p.unbind(-1)
    th = wrap(th)
    half = 0.5 * th
    small = th.abs() < SMALL_ANGLE
    safe = torch.where(small, torch.ones_like(half), half)
    a = torch.where(small, 1 - th * th / 12, safe * torch.cos(safe) / torch.sin(safe))
    return torch.stack([a * x + half * y, -half * x + a * y, th], -1)


def se2_compose(p, q):
    x, y, th = p.unbind(-1)
    qx, qy, qth = q.unbind(-1)
    s, c = torch.sin(th), torch.cos(th)
    return torch.stack([x + c * qx - s * qy, y + s * qx + c * qy, wrap(th + qth)], -1)


def se2_inverse(p):
    x, y, th = p.unbind(-1)
    s, c = torch.sin(th), torch.cos(th)
    return torch.stack([-c * x - s * y, s * x - c * y, wrap(-th)], -1)


# --------------------------------------------------------------------------------------------
# The network (sdk/flow/src/net.rs); parameter names match the Rust variables
# --------------------------------------------------------------------------------------------


def activation(name: str) -> nn.Module:
    return {"silu": nn.SiLU(), "mish": nn.Mish()}[name]


class Conv1dBlock(nn.Module):
    def __init__(self, cin, cout, k, groups, act):
        super().__init__()
        self.conv = nn.Conv1d(cin, cout, k, padding=k // 2)
        self.norm = nn.GroupNorm(groups, cout)
        self.act = act

    def forward(self, x):
        return self.act(self.norm(self.conv(x)))


class ResBlock(nn.Module):
    """Residual block with FiLM on its first convolution's output."""

    def __init__(self, cin, cout, k, groups, act):
        super().__init__()
        self.block0 = Conv1dBlock(cin, cout, k, groups, act)
        self.block1 = Conv1dBlock(cout, cout, k, groups, act)
        self.residual = nn.Conv1d(cin, cout, 1) if cin != cout else None

    def forward(self, x, scale, bias):
        h = self.block1(self.block0(x) * scale + bias)
        return h + (self.residual(x) if self.residual is not None else x)


class Level(nn.Module):
    def __init__(self, blocks, resample=None, resample_name=None):
        super().__init__()
        self.names = [f"res{b}" for b in range(len(blocks))]
        for name, block in zip(self.names, blocks):
            self.add_module(name, block)
        self.resample_name = resample_name
        if resample is not None:
            self.add_module(resample_name, resample)

    def blocks(self):
        return [getattr(self, n) for n in self.names]

    def resample(self, x):
        return getattr(self, self.resample_name)(x) if self.resample_name else x


class CondUnet1d(nn.Module):
    def __init__(self, net: dict):
        super().__init__()
        k, g = net["kernel_size"], net["n_groups"]
        self.act = act = activation(net["activation"])
        tdim, gdim = net["time_embed_dim"], net["goal_embed_dim"]
        self.tdim = tdim
        cond = tdim + net["bev_embed_dim"] + gdim

        self.time = nn.Module()
        self.time.fc0 = nn.Linear(tdim, 4 * tdim)
        self.time.fc1 = nn.Linear(4 * tdim, tdim)

        self.bev = nn.Module()
        cin = 3
        for i, c in enumerate(net["bev_channels"]):
            self.bev.add_module(f"conv{i}", nn.Conv2d(cin, c, 3, stride=2, padding=1))
            self.bev.add_module(f"norm{i}", nn.GroupNorm(g, c))
            cin = c
        self.bev.fc = nn.Linear(cin * 16, net["bev_embed_dim"])
        self.n_bev = len(net["bev_channels"])

        self.goal = nn.Module()
        self.goal.fc0 = nn.Linear(4, gdim)
        self.goal.fc1 = nn.Linear(gdim, gdim)

        # The crowd pathway ([net.crowd]): per waypoint, a two-layer MLP over every (crowd
        # point, waypoint) pair and a max over the points, appended to the 5 input channels.
        crowd = net.get("crowd")
        self.crowd_step = None
        if crowd:
            self.crowd = nn.Module()
            self.crowd.fc0 = nn.Linear(5, crowd["width"])
            self.crowd.fc1 = nn.Linear(crowd["width"], crowd["width"])
            self.crowd_step = crowd["step"]
        dims = [5 + (crowd["width"] if crowd else 0)] + list(net["down_dims"])
        levels, nb = len(net["down_dims"]), net["blocks_per_level"]
        self.film_channels = []

        def res(cin, cout):
            self.film_channels.append(cout)
            return ResBlock(cin, cout, k, g, act)

        self.unet = nn.Module()
        down = []
        for i in range(levels):
            din, dout = dims[i], dims[i + 1]
            blocks = [res(din if b == 0 else dout, dout) for b in range(nb)]
            last = i + 1 == levels
            ds = None if last else nn.Conv1d(dout, dout, 3, stride=2, padding=1)
            down.append(Level(blocks, ds, None if last else "downsample"))
        self.unet.down = nn.ModuleList(down)
        mid = dims[levels]
        self.unet.mid = nn.ModuleList([res(mid, mid) for _ in range(net["mid_blocks"])])
        up = []
        for i in reversed(range(1, levels)):
            din, dout = dims[i], dims[i + 1]
            blocks = [res(2 * dout if b == 0 else din, din) for b in range(nb)]
            upsample = nn.ConvTranspose1d(din, din, 4, stride=2, padding=1)
            up.append(Level(blocks, upsample, "upsample"))
        self.unet.up = nn.ModuleList(up)
        self.unet.film = nn.Linear(cond, sum(2 * c for c in self.film_channels))
        self.unet.final_block = Conv1dBlock(dims[1], dims[1], k, g, act)
        self.unet.final_conv = nn.Conv1d(dims[1], 3, 1)

    def encode_condition(self, bev, goal_vel):
        h = bev
        for i in range(self.n_bev):
            h = self.act(getattr(self.bev, f"norm{i}")(getattr(self.bev, f"conv{i}")(h)))
        h = F.adaptive_avg_pool2d(h, (4, 4)).flatten(1)
        bev_emb = self.act(self.bev.fc(h))
        goal_emb = self.goal.fc1(self.act(self.goal.fc0(goal_vel)))
        return torch.cat([bev_emb, goal_emb], 1)

    def encode_time(self, t):
        half = self.tdim // 2
        freqs = torch.exp(torch.arange(half, dtype=t.dtype) * -(math.log(10000.0) / (half - 1)))
        args = t.view(-1, 1) * 100.0 * freqs.view(1, -1)
        emb = torch.cat([args.sin(), args.cos()], 1)
        return self.time.fc1(self.act(self.time.fc0(emb)))

    def crowd_features(self, x, points):
        """`[B, width, T]` of trajectory features `x` (`[B, 5, T]`) and crowd points `points`
        (`[B or 1, N, 5]`: x, y, v_x, v_y in network units, present), as
        `CondUnet1d::crowd_features` computes them."""
        t_len = x.shape[2]
        tau = ((torch.arange(t_len, dtype=x.dtype) + 1.0) * self.crowd_step).view(1, 1, -1)
        px, py, cs, sn = (x[:, c].unsqueeze(1) for c in range(4))
        qx, qy, vx, vy, present = (points[:, :, c].unsqueeze(2) for c in range(5))
        dx, dy = qx + vx * tau - px, qy + vy * tau - py
        bx, by = cs * dx + sn * dy, cs * dy - sn * dx
        dist = (bx.square() + by.square() + 1e-6).sqrt()
        b, n = bx.shape[0], bx.shape[1]
        ux = (cs * vx + sn * vy).expand(b, n, t_len)
        uy = (cs * vy - sn * vx).expand(b, n, t_len)
        pair = torch.stack([bx, by, dist, ux, uy], 3)
        h = self.act(self.crowd.fc1(self.act(self.crowd.fc0(pair))))
        present = present.unsqueeze(3)
        pooled = (h + (present - 1.0) * 1e4).amax(1) * present.amax(1)
        return pooled.permute(0, 2, 1)

    def forward(self, x, t, cond, points=None):
        if self.crowd_step is not None:
            if points is None:
                raise ValueError("this network has a crowd pathway: pass the crowd points")
            x = torch.cat([x, self.crowd_features(x, points)], 1)
        c = torch.cat([self.encode_time(t), cond], 1)
        film = self.unet.film(self.act(c)).split([2 * ch for ch in self.film_channels], 1)
        film = iter([f.view(-1, 2, ch, 1).unbind(1) for f, ch in zip(film, self.film_channels)])
        h, skips = x, []
        for level in self.unet.down:
            for block in level.blocks():
                h = block(h, *next(film))
            skips.append(h)
            h = level.resample(h)
        for block in self.unet.mid:
            h = block(h, *next(film))
        for level in self.unet.up:
            h = torch.cat([h, skips.pop()], 1)
            for block in level.blocks():
                h = block(h, *next(film))
            h = level.resample(h)
        return self.unet.final_conv(self.unet.final_block(h))


# --------------------------------------------------------------------------------------------
# Training (sdk/flow/src/train.rs)
# --------------------------------------------------------------------------------------------


@dataclass
class Norm:
    position_scale: float
    velocity_std: list[float]
    goal_scale: float
    speed_scale: float


def estimate_normalisation(data: Tuples, gen: torch.Generator) -> Norm:
    """`Normalisation::estimate`: RMS future distance, goal distance and ego speed, and the RMS
    of the target velocity over source draws for up to 4096 examples."""
    s = max(data.future[..., :2].square().sum(-1).mean().sqrt().item(), 0.1)
    goal = max(data.goal.square().sum(-1).mean().sqrt().item(), 0.1)
    speed = max(data.velocity.square().sum(-1).mean().sqrt().item(), 0.1)
    pick = torch.randperm(len(data.future), generator=gen)[:4096]
    x1 = data.future[pick] / torch.tensor([s, s, 1.0], dtype=torch.float64)
    x0 = se2_exp(torch.randn(x1.shape, dtype=torch.float64, generator=gen))
    xi = se2_log(se2_compose(se2_inverse(x0), x1))
    std = xi.square().mean((0, 1)).sqrt().clamp_min(1e-3).tolist()
    return Norm(s, std, goal, speed)


@dataclass
class Batch:
    x: torch.Tensor  # [B, 5, T] float32
    t: torch.Tensor  # [B] float32
    bev: torch.Tensor  # [B, 3, H, W] float32
    goal_vel: torch.Tensor  # [B, 4] float32
    target: torch.Tensor  # [B, 3, T] float32


class BatchBuilder:
    def __init__(self, data: Tuples, norm: Norm, time_cfg: dict, gen: torch.Generator):
        self.data, self.norm, self.gen = data, norm, gen
        inv_speed = 1.0 / norm.speed_scale
        self.bev_scale = torch.tensor([1.0, inv_speed, inv_speed]).view(1, 3, 1, 1)
        s = norm.position_scale
        self.pose_scale = torch.tensor([s, s, 1.0], dtype=torch.float64)
        self.velocity_std = torch.tensor(norm.velocity_std, dtype=torch.float64)
        alpha, beta = (torch.tensor(time_cfg[k], dtype=torch.float64) for k in ("alpha", "beta"))
        self.beta = torch.distributions.Beta(alpha, beta)
        self.s = time_cfg["s"]
        horizon = data.future.shape[1]
        self.place = torch.arange(1, horizon + 1, dtype=torch.float32) / horizon

    def build(self, idx, xi0=None, t=None) -> Batch:
        """The batch of examples `idx`; flow times and source twists drawn unless given."""
        b, horizon = len(idx), self.data.future.shape[1]
        if t is None:
            t = self.s * (1 - self.beta.sample((b,)))
        if xi0 is None:
            xi0 = torch.randn(b, horizon, 3, dtype=torch.float64, generator=self.gen)
        x, target = self.trajectories(idx, xi0, t)
        bev, goal_vel = self.conditions(idx)
        return Batch(x=x, t=t.float(), bev=bev, goal_vel=goal_vel, target=target)

    def trajectories(self, idx, xi0, t):
        """Features of the geodesic points `x_t` and the standardised targets `xi`."""
        x1 = self.data.future[idx] / self.pose_scale
        x0 = se2_exp(xi0)
        xi = se2_log(se2_compose(se2_inverse(x0), x1))
        xt = se2_compose(x0, se2_exp(xi * t.view(-1, 1, 1)))
        th = xt[..., 2]
        place = self.place.expand(len(idx), -1)
        x = torch.stack([xt[..., 0], xt[..., 1], th.cos(), th.sin()], 1).float()
        x = torch.cat([x, place.unsqueeze(1)], 1)
        target = (xi / self.velocity_std).float().transpose(1, 2)
        return x, target

    def conditions(self, idx):
        """The normalised BEV stack and goal/velocity conditions."""
        d, n = self.data, self.norm
        goal_vel = torch.cat([d.goal[idx] / n.goal_scale, d.velocity[idx] / n.speed_scale], 1)
        return d.bev[idx] * self.bev_scale, goal_vel.float()


class EpochSampler:
    """Batch indices: a random permutation per epoch, walked in order across epochs."""

    def __init__(self, n: int, batch: int, gen: torch.Generator):
        self.n, self.batch, self.gen = n, batch, gen
        self.order, self.pos = torch.randperm(n, generator=gen), 0

    def next(self) -> torch.Tensor:
        out = []
        need = self.batch
        while need:
            take = min(need, self.n - self.pos)
            out.append(self.order[self.pos : self.pos + take])
            self.pos += take
            need -= take
            if self.pos == self.n:
                self.order, self.pos = torch.randperm(self.n, generator=self.gen), 0
        return torch.cat(out)


def lr_lambda(opts: dict):
    def f(step):
        if step < opts["warmup_steps"]:
            return (step + 1) / opts["warmup_steps"]
        span = max(opts["steps"] - opts["warmup_steps"], 1)
        p = min((step - opts["warmup_steps"]) / span, 1.0)
        lr = opts["lr_min"] + 0.5 * (opts["lr"] - opts["lr_min"]) * (1 + math.cos(math.pi * p))
        return lr / opts["lr"]

    return f


class Trainer:
    def __init__(self, cfg: dict, data: Tuples):
        opts = cfg["train"]
        if opts.get("mirror", False) or opts.get("path_sigma", 0.0) != 0.0:
            raise SystemExit("train.mirror and train.path_sigma are not implemented (both off)")
        if cfg["net"].get("crowd") or opts.get("clearance"):
            raise SystemExit(
                "training with [net.crowd] or [train.clearance] is not implemented here; "
                "torch_planning_call.py runs such a network"
            )
        torch.manual_seed(opts["seed"])
        self.opts = opts
        self.gen = torch.Generator().manual_seed(opts["seed"])
        self.norm = estimate_normalisation(data, self.gen)
        self.model = CondUnet1d(cfg["net"])
        self.ema = copy.deepcopy(self.model).requires_grad_(False)
        self.opt = torch.optim.AdamW(
            self.model.parameters(),
            lr=opts["lr"],
            betas=(opts["beta1"], opts["beta2"]),
            eps=opts["eps"],
            weight_decay=opts["weight_decay"],
        )
        self.sched = torch.optim.lr_scheduler.LambdaLR(self.opt, lr_lambda(opts))
        self.builder = BatchBuilder(data, self.norm, opts["time"], self.gen)
        self.sampler = EpochSampler(len(data.future), opts["batch_size"], self.gen)
        self.step = 0

    def train_step(self) -> dict:
        """One optimiser step; returns the loss and the wall time of each phase (seconds)."""
        t0 = time.perf_counter()
        batch = self.builder.build(self.sampler.next())
        t1 = time.perf_counter()
        self.opt.zero_grad()
        pred = self.model(batch.x, batch.t, self.model.encode_condition(batch.bev, batch.goal_vel))
        loss = F.mse_loss(pred, batch.target)
        loss_value = loss.item()
        if not math.isfinite(loss_value):
            raise FloatingPointError(f"diverged at step {self.step}")
        t2 = time.perf_counter()
        loss.backward()
        t3 = time.perf_counter()
        nn.utils.clip_grad_norm_(self.model.parameters(), self.opts["grad_clip"])
        self.opt.step()
        self.sched.step()
        decay = min(self.opts["ema_decay"], (1 + self.step) / (10 + self.step))
        with torch.no_grad():
            for e, p in zip(self.ema.parameters(), self.model.parameters()):
                e.lerp_(p, 1 - decay)
        self.step += 1
        t4 = time.perf_counter()
        return {
            "loss": loss_value,
            "batch": t1 - t0,
            "forward": t2 - t1,
            "backward": t3 - t2,
            "update": t4 - t3,
            "step": t4 - t0,
        }


# --------------------------------------------------------------------------------------------
# Modes
# --------------------------------------------------------------------------------------------


PHASES = ["batch", "forward", "backward", "update"]
PHASE_NAMES = ["batch building", "forward + loss", "backward", "clip + AdamW + EMA"]


def bench(cfg: dict, cache: Path, steps: int, warmup: int, threads: int):
    torch.set_num_threads(threads)
    if cfg["data"].get("train_fraction", 1.0) != 1.0:
        raise SystemExit("only data.train_fraction = 1 is implemented")
    start = time.perf_counter()
    data = load_split(cache, "train")
    print(f"loaded {len(data.future)} training tuples in {time.perf_counter() - start:.1f} s")
    trainer = Trainer(cfg, data)
    n_params = sum(p.numel() for p in trainer.model.parameters())
    print(f"{n_params} parameters; normalisation {trainer.norm}")
    for _ in range(warmup):
        trainer.train_step()
    times = [trainer.train_step() for _ in range(steps)]
    ms = {k: [1e3 * t[k] for t in times] for k in PHASES + ["step"]}
    b = cfg["train"]["batch_size"]
    med = statistics.median(ms["step"])
    print(
        f"train step: batch {b}, {threads} torch threads, {steps} steps after {warmup} warm-up: "
        f"median {med:.2f} ms, mean {statistics.fmean(ms['step']):.2f} ms per step "
        f"({b * 1e3 / med:.0f} samples/s at the median)"
    )
    for key, name in zip(PHASES, PHASE_NAMES):
        med, mean = statistics.median(ms[key]), statistics.fmean(ms[key])
        print(f"  {name:<20} median {med:7.2f} ms  mean {mean:7.2f} ms")
    print(f"  loss first {times[0]['loss']:.4f}, last {times[-1]['loss']:.4f}")


def bench_batch_pieces(cfg: dict, cache: Path, steps: int, threads: int):
    """Median time of each piece of batch building (this implementation)."""
    torch.set_num_threads(threads)
    data = load_split(cache, "train")
    trainer = Trainer(cfg, data)
    bld = trainer.builder
    idx = trainer.sampler.next()
    b, horizon = len(idx), data.future.shape[1]
    t = bld.s * (1 - bld.beta.sample((b,)))
    xi0 = torch.randn(b, horizon, 3, dtype=torch.float64)
    pieces = {
        "batch indices": trainer.sampler.next,
        "flow times (Beta)": lambda: bld.s * (1 - bld.beta.sample((b,))),
        "source twists (randn)": lambda: torch.randn(
            b, horizon, 3, dtype=torch.float64, generator=bld.gen
        ),
        "geodesic, features, targets": lambda: bld.trajectories(idx, xi0, t),
        "BEV stack + goal/velocity": lambda: bld.conditions(idx),
        "whole batch (as in a step)": lambda: bld.build(trainer.sampler.next()),
    }
    for name, f in pieces.items():
        for _ in range(5):
            f()
        ts = []
        for _ in range(steps):
            t0 = time.perf_counter()
            f()
            ts.append(1e3 * (time.perf_counter() - t0))
        print(f"  {name:<40} median {statistics.median(ts):7.3f} ms")


def check(cfg: dict, cache: Path, model_dir: Path, rust_file: Path):
    torch.set_num_threads(1)
    card = tomllib.loads((model_dir / "model.toml").read_text())
    r = read_safetensors(rust_file)
    net = CondUnet1d(card["net"])
    n_params = sum(p.numel() for p in net.parameters())
    weights = read_safetensors(model_dir / card["weights"])
    net.load_state_dict(weights, strict=True)
    print(
        f"PyTorch module: {n_params} parameters (card: {card['complexity']['parameters']}); "
        "shipped weights loaded by name, strict"
    )

    def rel(a, b):
        return ((a.double() - b.double()).abs().max() / b.double().abs().max()).item()

    def elem(a, b, floor=1e-3):
        a, b = a.double(), b.double()
        return ((a - b).abs() / (b.abs() + floor * b.abs().max())).max().item()

    # 1. The network on the Rust inputs.
    cond = net.encode_condition(r["bev"], r["goal_vel"])
    pred = net(r["x"], r["t"], cond)
    loss = F.mse_loss(pred, r["target"])
    loss.backward()
    print(f"rows {len(r['idx'])}: network on the Rust inputs")
    print(f"  condition embedding  max|d|/max|ref| {rel(cond, r['cond']):.2e}")
    print(
        f"  output               max|d|/max|ref| {rel(pred, r['pred']):.2e}, "
        f"max|d| {(pred - r['pred']).abs().max().item():.2e}, "
        f"|d|_2/|ref|_2 {((pred - r['pred']).norm() / r['pred'].norm()).item():.2e}, "
        f"max |d|/(|ref| + 1e-3 max|ref|) {elem(pred, r['pred']):.2e}"
    )
    ours, theirs = loss.item(), r["loss"].item()
    rel_loss = abs(ours - theirs) / theirs
    print(f"  loss                 {ours:.8f} vs Rust {theirs:.8f} (rel {rel_loss:.2e})")
    worst = max(((rel(p.grad, r[f"grad.{name}"]), name) for name, p in net.named_parameters()))
    n_tensors = len(list(net.parameters()))
    print(
        f"  gradients            worst tensor max|d|/max|ref| {worst[0]:.2e} ({worst[1]}; "
        f"{n_tensors} tensors, {n_params} values)"
    )

    # 2. This batch building from the same tuples, twists and times.
    data = load_split(cache, "train")
    nm = card["normalisation"]
    norm = Norm(nm["position_scale"], nm["velocity_std"], nm["goal_scale"], nm["speed_scale"])
    bld = BatchBuilder(data, norm, cfg["train"]["time"], torch.Generator())
    b = bld.build(r["idx"], xi0=r["xi0"], t=r["t64"])
    print("batch building from the same tuple indices, source twists and flow times")
    for name in ("x", "t", "bev", "goal_vel", "target"):
        got, ref = getattr(b, name), r[name]
        diff, scale = (got - ref).abs().max().item(), ref.abs().max().item()
        print(f"  {name:<9} max|d| {diff:.2e}  (max|ref| {scale:.3g})")
    occupied = (r["bev"][:, 0] > 0).sum().item()
    print(f"  ({occupied} occupied BEV cells in these rows)")
    with torch.no_grad():
        own = net(b.x, b.t, net.encode_condition(b.bev, b.goal_vel))
    print(f"  network on these inputs vs Rust output: max|d|/max|ref| {rel(own, r['pred']):.2e}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=Path("sdk/configs/train.toml"))
    ap.add_argument("--cache", type=Path, help="tuple cache (default: data.cache of the config)")
    ap.add_argument("--bench", action="store_true", help="time training steps")
    ap.add_argument("--pieces", action="store_true", help="time the pieces of batch building")
    ap.add_argument(
        "--check", type=Path, metavar="RUST_FILE", help="compare with the Rust example's file"
    )
    ap.add_argument(
        "--model", type=Path, default=Path("models/human2nav-cfm"), help="model folder (--check)"
    )
    ap.add_argument("--steps", type=int, default=30)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    cfg = tomllib.loads(args.config.read_text())
    cache = args.cache or Path(cfg["data"]["cache"])
    if args.check:
        check(cfg, cache, args.model, args.check)
    if args.bench:
        bench(cfg, cache, args.steps, args.warmup, args.threads)
    if args.pieces:
        bench_batch_pieces(cfg, cache, args.steps, args.threads)
    if not (args.check or args.bench or args.pieces):
        ap.print_help()


if __name__ == "__main__":
    main()

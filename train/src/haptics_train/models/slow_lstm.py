"""`lstm_slow`: an LSTM whose state steps at the object's pace (100 Hz by default), trained
over horizons of seconds, served once per control step by the unchanged stateful contract.

Why: the foam's memory (relaxation, the permanent set) lasts seconds to minutes, but an LSTM
stepped at the 10 kHz loop rate and trained on 5 ms windows (`lstm`) never sees a horizon that
long; the back-propagation through 30 000 loop steps that a 3 s window would take is out of
reach on a CPU. Here the recurrent state advances once per *block* of control steps (the
block's mean kinematics), so 3 s are 300 state steps, while the force is still produced at
every control step from the last complete block's state and the current kinematics:

    z_t     = scaled features of control step t (x, v by default; kinematics only, so the
              model cannot feed its own error back and drift)
    F(t)    = head([h_k, z_t])                    h_k: the state after the last complete block
    block k+1 complete (N control steps):  h_{k+1}, c_{k+1} = LSTM(mean z over the block; h_k, c_k)

The served graph does the block bookkeeping itself, so infer-server and rt-loop step it like
any stateful model (docs/model-contract.md): `h_in`/`h_out` carry [h (H), the block's running
sum of z (f), the block's step count (1)]; `c_in`/`c_out` carry [c (H), zeros]. The state
size is H + f + 1 for both. A scaled feature that is not finite or beyond 1e6 counts as 0,
so one bad sample cannot poison the state.

Training: truncated back-propagation through time at the block rate. `streams` cursors walk the
recordings `horizon_s` at a time, carrying the (detached) state from window to window; a cursor
that reaches the end restarts at a random place, and its first `burn_in_s` are not scored (its
zero state is not the object's state there) unless it restarts at a recording's start, where the
object is at rest like the served model's zero state. The head is scored on `rows_per_block`
rows spread over each block. The target is what the bench recorded (the RFOB estimate): with
friction compensation off it contains the bench's friction, which this model (unlike
`structured`) does not separate; with compensation on it is the object alone.

Sequences layout (`models.base`): `fit(X, y, info)`. Fitted attributes: `net_` (scalers, LSTM,
head), `serve_dt_` (the loop's period it is served at, `haptics.step_s`), `block_rows_` (rows
per block in the training recordings), `block_steps_` (control
steps per block when served), `train_info_`.
"""

from __future__ import annotations

import time

import numpy as np
import onnx
import torch
from onnx import helper
from torch import nn
from tqdm.auto import tqdm

from ..data import SequenceInfo
from .base import ForceModel, check_sequences, serve_dt, step_dt
from .networks import ASINH_CLIP, InputScaler, TargetScaler
from .onnx_graph import (
    Graph,
    floats_attr,
    fused_stateful_model,
    row,
    scaled_input,
    stateful_model,
)

SLOW_LSTM_DEFAULT: dict = {
    "hidden": 48,
    "head": 32,
    # the state's step: the object's fastest time constant is tens of ms (structured's
    # branches start at 20 ms), so 10 ms blocks keep it while a 3 s window is 300 steps
    "state_step_s": 0.01,
    "horizon_s": 3.0,
    "burn_in_s": 5.0,
    "rows_per_block": 8,
    "streams": 32,
    # chosen on the sponge's validation recording: 1500 -> 0.588 N, 3000 -> 0.555 N (about
    # two minutes on the 2-core machine)
    "iterations": 3000,
    "lr": 3e-3,
}

#: a scaled feature beyond this (or not finite) counts as 0 (training and served alike)
_Z_LIMIT = 1e6


def _clean(z: torch.Tensor) -> torch.Tensor:
    return torch.where(torch.abs(z) < _Z_LIMIT, z, torch.zeros_like(z))


class SlowLSTMNet(nn.Module):
    def __init__(self, inp: InputScaler, hidden: int, head: int, out: TargetScaler) -> None:
        super().__init__()
        nf = len(inp.mu)
        self.inp = inp
        self.lstm = nn.LSTM(nf, hidden, batch_first=True)
        self.head = nn.Sequential(nn.Linear(hidden + nf, head), nn.Tanh(), nn.Linear(head, 1))
        self.out = out

    def scaled(self, x: torch.Tensor) -> torch.Tensor:
        return _clean(self.inp(x))


def slow_lstm_graph(net: SlowLSTMNet, block_steps: int) -> onnx.ModelProto:
    """One control step of the served graph (see the module docstring), built by hand
    (models/onnx_graph.py says why): the scaler folded into one multiply-add, the head's target
    scaling folded into its last layer, the LSTM cell as one MatMul over [h, mean z] for the
    four gates (ordered i, f, o, g: one Sigmoid, one Tanh), and the block's bookkeeping as
    one Where per state tensor."""
    hid, nf = net.lstm.hidden_size, net.lstm.input_size
    f64 = lambda t: t.detach().double().numpy()  # noqa: E731
    inp = net.inp
    g = Graph("lstm_slow")
    z = scaled_input(g, "features", f64(inp.soft).astype(bool), f64(inp.s), f64(inp.mu),
                     f64(inp.sd), ASINH_CLIP)  # fmt: skip
    zero = g.const(0.0)
    z = g.op("Where", g.op("Less", g.op("Abs", z), g.const(_Z_LIMIT)), z, zero)  # [1, 1, f]
    h, acc, cnt = g.split("h_in", [hid, nf, 1], axis=2, hint="h")
    c, c_rest = g.split("c_in", [hid, nf + 1], axis=2, hint="c")
    # the force, from the last complete block's state: head(cat[h, z]) scaled to N
    lin1, lin2 = net.head[0], net.head[2]
    pre = g.op("Add", g.op("MatMul", g.op("Concat", h, z, axis=2), g.const(f64(lin1.weight).T)),
               g.const(row(f64(lin1.bias))))  # fmt: skip
    scale, offset = float(net.out.scale), float(net.out.offset)
    force = g.op("Add", g.op("MatMul", g.op("Tanh", pre), g.const(f64(lin2.weight).T * scale)),
                 g.const(row(f64(lin2.bias) * scale + offset)))  # fmt: skip
    acc = g.op("Add", acc, z)
    cnt = g.op("Add", cnt, g.const(1.0))
    full = g.op("Greater", cnt, g.const(block_steps - 0.5))
    mean = g.op("Div", acc, cnt)
    # torch's gate rows are i, f, g, o; reordered i, f, o, g
    order = np.r_[0:2 * hid, 3 * hid:4 * hid, 2 * hid:3 * hid]
    w = np.concatenate([f64(net.lstm.weight_hh_l0), f64(net.lstm.weight_ih_l0)], axis=1)[order]
    b = (f64(net.lstm.bias_ih_l0) + f64(net.lstm.bias_hh_l0))[order]
    gates = g.op("Add", g.op("MatMul", g.op("Concat", h, mean, axis=2), g.const(w.T)),
                 g.const(row(b)))  # fmt: skip
    sig, cand = g.split(gates, [3 * hid, hid], axis=2, hint="gates")
    i, f, o = g.split(g.op("Sigmoid", sig), [hid, hid, hid], axis=2, hint="ifo")
    c2 = g.op("Add", g.op("Mul", f, c), g.op("Mul", i, g.op("Tanh", cand)))
    h2 = g.op("Mul", o, g.op("Tanh", c2))
    # a complete block: the new state and an empty block; else the old state and the sums
    h_out = g.op("Where", full, g.op("Concat", h2, g.const(np.zeros((1, 1, nf + 1))), axis=2),
                 g.op("Concat", h, acc, cnt, axis=2))  # fmt: skip
    c_out = g.op("Where", full, g.op("Concat", c2, c_rest, axis=2), "c_in")
    return stateful_model(g, nf, hid + nf + 1, force, h_out, c_out)


def slow_lstm_fused(net: SlowLSTMNet, block_steps: int) -> onnx.ModelProto:
    """One control step as one `ai.haptics:SlowLstmStep` node (fused-ops/src/slow_lstm.rs;
    attribute names: its `from_attrs`): the same state layout and arithmetic as
    `slow_lstm_graph`, the standardisation as z * (1 / sd) + (-mu / sd) (the graph's), the
    cell's weights in torch's gate order, the target scaling folded into the head's output."""
    hid, nf = net.lstm.hidden_size, net.lstm.input_size
    f64 = lambda t: t.detach().double().numpy()  # noqa: E731
    inp = net.inp
    soft = f64(inp.soft).astype(bool)
    mu, sd = f64(inp.mu), f64(inp.sd)
    lin1, lin2 = net.head[0], net.head[2]
    scale, offset = float(net.out.scale), float(net.out.offset)
    attrs = [
        floats_attr("soft_scale", np.where(soft, f64(inp.s), 0.0)),
        helper.make_attribute("clip", float(ASINH_CLIP)),
        floats_attr("feature_scale", 1.0 / sd),
        floats_attr("feature_offset", -mu / sd),
        floats_attr("input_weights", f64(net.lstm.weight_ih_l0)),
        floats_attr("recurrent_weights", f64(net.lstm.weight_hh_l0)),
        floats_attr("biases", f64(net.lstm.bias_ih_l0) + f64(net.lstm.bias_hh_l0)),
        floats_attr("head_weights", f64(lin1.weight)),
        floats_attr("head_biases", f64(lin1.bias)),
        floats_attr("out_weights", f64(lin2.weight)[0] * scale),
        helper.make_attribute("out_bias", float(f64(lin2.bias)[0] * scale + offset)),
        helper.make_attribute("block_steps", float(block_steps)),
    ]
    return fused_stateful_model("SlowLstmStep", attrs, nf, hid + nf + 1, "lstm_slow")


def _blocks(x: np.ndarray, rows: int) -> np.ndarray:
    """[n, f] -> [n // rows, rows, f] (the partial last block dropped)."""
    nb = len(x) // rows
    return x[: nb * rows].reshape(nb, rows, *x.shape[1:])


class SlowLSTMModel(ForceModel):
    algo = "lstm_slow"
    kind = "stateful"
    layout = "sequences"
    defaults = SLOW_LSTM_DEFAULT

    @property
    def name(self) -> str:
        # `lstm_slow` names the default (x, v) like `structured`: the spec is the file name
        return "lstm_slow" if self.feature_set == "x_v" else f"lstm_slow_{self.feature_set}"

    @property
    def state_size(self) -> int:
        return int(self.hyper["hidden"]) + len(self.features) + 1

    def fit(
        self, X: list[np.ndarray], y: list[np.ndarray], info: list[SequenceInfo]
    ) -> SlowLSTMModel:
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        h = self.hyper
        torch.manual_seed(self.seed)
        rng = np.random.default_rng(self.seed)
        dt = step_dt(self.name, info)
        rows = max(1, round(float(h["state_step_s"]) / dt))
        self.block_rows_ = rows
        block_s = rows * dt
        # control steps per block when served: the block's duration at the loop's period (a
        # recording decimated k times has k steps a row; a 50 Hz import's rows are 200 steps)
        self.serve_dt_ = serve_dt(self.name, info)
        self.block_steps_ = max(1, round(block_s / self.serve_dt_))
        xs = np.concatenate([x[:: max(1, i.stride)] for x, i in zip(seqs, info, strict=True)])
        ys = np.concatenate([v[:: max(1, i.stride)] for v, i in zip(targets, info, strict=True)])
        ok = np.isfinite(xs).all(axis=1) & np.isfinite(ys)
        net = SlowLSTMNet(
            InputScaler(self.features, xs[ok]), int(h["hidden"]), int(h["head"]),
            TargetScaler(float(ys[ok].mean()), float(ys[ok].std()) or 1.0),
        )  # fmt: skip
        per = max(1, min(int(h["rows_per_block"]), rows))
        pick = np.unique(np.linspace(0, rows - 1, per).round().astype(int))
        # per recording: block means Z [nb, f], the head's rows R [nb, r, f], targets Y [nb, r]
        data = []
        with torch.no_grad():
            for xk, yk in zip(seqs, targets, strict=True):
                z = net.scaled(torch.tensor(xk, dtype=torch.float32)).numpy()
                zb = _blocks(z, rows)
                yb = _blocks(net.out.encode(yk).astype(np.float32), rows)[:, pick]
                data.append((torch.tensor(zb.mean(axis=1)), torch.tensor(zb[:, pick]),
                             torch.tensor(yb)))  # fmt: skip
        lengths = np.array([len(d[0]) for d in data])
        chunk = max(2, round(float(h["horizon_s"]) / block_s))
        burn = round(float(h["burn_in_s"]) / block_s)
        if lengths.min() <= 2 * chunk:
            raise ValueError(f"{self.name}: recordings shorter than two windows "
                             f"({2 * chunk * block_s:.1f} s)")  # fmt: skip
        hid, n_streams = int(h["hidden"]), int(h["streams"])

        def restart() -> list[int]:
            k = int(rng.choice(len(data), p=lengths / lengths.sum()))
            # a quarter of the restarts begin at a recording's start, where the object is at
            # rest like the served model's zero state
            p = 0 if rng.random() < 0.25 else int(rng.integers(0, lengths[k] - 2 * chunk))
            return [k, p, 0 if p == 0 else p + burn]

        cursors = [restart() for _ in range(n_streams)]
        hs = torch.zeros(1, n_streams, hid)
        cs = torch.zeros(1, n_streams, hid)
        iters = int(h["iterations"])
        opt = torch.optim.Adam(net.parameters(), lr=float(h["lr"]))
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iters)
        t0 = time.perf_counter()
        losses: list[float] = []
        bar = tqdm(range(iters), desc=f"{self.name} TBPTT", disable=not self.progress)
        for _ in bar:
            zb = torch.stack([data[k][0][p : p + chunk] for k, p, _ in cursors])
            rb = torch.stack([data[k][1][p : p + chunk] for k, p, _ in cursors])
            yb = torch.stack([data[k][2][p : p + chunk] for k, p, _ in cursors])
            idx = torch.arange(chunk)
            scored = torch.stack([idx + p >= w for _, p, w in cursors])  # [S, C]
            mask = scored.unsqueeze(2) & torch.isfinite(yb)
            opt.zero_grad()
            out, (hn, cn) = net.lstm(zb, (hs, cs))
            hprev = torch.cat([hs.transpose(0, 1), out[:, :-1]], dim=1)  # h_{k-1} for block k
            hr = hprev.unsqueeze(2).expand(-1, -1, rb.shape[2], -1)
            pred = net.head(torch.cat([hr, rb], dim=3))[..., 0]
            if mask.any():
                loss = ((pred - torch.nan_to_num(yb)) ** 2)[mask].mean()
                loss.backward()
                nn.utils.clip_grad_norm_(net.parameters(), 1.0)
                opt.step()
                losses.append(loss.item())
                sched.step()  # (a window all burn-in trains nothing and takes no step)
            hs, cs = hn.detach(), cn.detach()
            for i, (k, p, w) in enumerate(cursors):
                if p + 2 * chunk > lengths[k]:
                    cursors[i] = restart()
                    hs[:, i] = 0.0
                    cs[:, i] = 0.0
                else:
                    cursors[i] = [k, p + chunk, w]
            if len(losses) % 50 == 0 and losses:
                bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4g}")
        net.eval()
        self.net_ = net
        self.n_features_in_ = len(self.features)
        self.train_info_ = {
            "state_step_s": block_s,
            "block_rows": rows,
            "block_control_steps": self.block_steps_,
            "horizon_s_effective": chunk * block_s,
            "burn_in_s": burn * block_s,
            "blocks_seen": iters * n_streams * chunk,
            "fit_seconds": round(time.perf_counter() - t0, 2),
            "final_train_loss_scaled": float(np.mean(losses[-50:])) if losses else None,
        }
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """One sequence from zero state, blocks aligned with its first row: what the served
        graph gives when stepped through the same rows."""
        self._check_fitted()
        x = self._check_X(X)
        net, rows = self.net_, self.block_rows_
        out = np.empty(len(x))
        with torch.no_grad():
            z = net.scaled(torch.tensor(x, dtype=torch.float32))
            nb = len(x) // rows
            zb = z[: nb * rows].reshape(nb, rows, -1).mean(dim=1)
            hid = net.lstm.hidden_size
            hk = torch.zeros(1, hid)
            if nb:
                hs, _ = net.lstm(zb.unsqueeze(0))
                hk = torch.cat([hk, hs[0]], dim=0)  # hk[k]: the state rows of block k use
            which = torch.clamp(torch.arange(len(x)) // rows, max=len(hk) - 1)
            for i in range(0, len(x), 200_000):
                sl = slice(i, i + 200_000)
                y = net.head(torch.cat([hk[which[sl]], z[sl]], dim=1))
                out[sl] = net.out(y)[:, 0].numpy()
        return out

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:SlowLstmStep` node (the fused operator: needs
        libhaptics_fused_ops.so where it runs), or with `fused=False` the multi-node graph
        (same state, same step)."""
        self._check_fitted()
        return (slow_lstm_fused if fused else slow_lstm_graph)(self.net_, self.block_steps_)

"""The dense network and the LSTM (PyTorch), with all scaling inside the exported graph.

Input scaling: the ratio features F_res(t-1)/x, /v, /a reach +-1e7 near zero divisors, which
wrecks plain standardisation, so they pass through asinh(z / s) first (s = the median |z| of the
training rows: linear near zero, logarithmic in the tails), then every feature is standardised.
The target is standardised too and the output de-standardised in the graph. asinh is
written out with Log/Sqrt inside the graph, so the served model takes the raw features the
loop computes.
"""

from __future__ import annotations

import math
import time
import warnings

import numpy as np
import onnx
import torch
from torch import nn
from tqdm.auto import tqdm

from ..data import SequenceInfo
from ..features import F_PREVIOUS, KINEMATICS, PREVIOUS_FORCE_FEATURES, RATIO_DIVISORS
from .base import ForceModel, check_rows, check_sequences
from .network_graphs import dense_fused, dense_graph, lstm_fused, lstm_graph

#: |z / s| beyond this is clipped before asinh (asinh(1e15) = 35.2; (1e15)^2 fits float32)
ASINH_CLIP = 1e15


#: The `aux` columns the networks take beside their features (feedback-noise training):
#: the previous force and the three divisors of the ratio features.
AUX = (F_PREVIOUS, *KINEMATICS)


def _aux_for(model: ForceModel, aux: object, noisy: bool) -> None:
    if noisy and aux is None:
        raise ValueError(
            f"{model.name}: feedback noise needs `aux` ({', '.join(AUX)} of the same rows)"
        )


def perturb_previous_force(
    x: torch.Tensor, features: tuple[str, ...], aux: torch.Tensor, e: torch.Tensor
) -> torch.Tensor:
    """Raw features as if the previous force had been F(t-1) + e (the error a model's own
    prediction carries in closed loop): ratios recomputed where their divisor is non-zero
    (held otherwise), f_previous shifted. `aux` = [F(t-1), x, v, a] of the same rows."""
    x = x.clone()
    fp = aux[..., 0] + e
    for j, f in enumerate(features):
        if f == F_PREVIOUS:
            x[..., j] = fp
        elif f in RATIO_DIVISORS:
            d = aux[..., 1 + KINEMATICS.index(RATIO_DIVISORS[f])]
            safe = torch.where(d != 0, d, torch.ones_like(d))
            x[..., j] = torch.where(d != 0, fp / safe, x[..., j])
    return x


def resolve_feedback_noise(h: dict, y: np.ndarray) -> float:
    """The feedback-noise scale in N: `feedback_noise` when given, else `feedback_noise_frac`
    times the training force's range (1st to 99th percentile), else 0. A fixed newton figure
    would be twice the whole range of a 1 N elastomer test and a tenth of a 20 N one."""
    if h.get("feedback_noise") is not None and float(h["feedback_noise"]) > 0:
        return float(h["feedback_noise"])
    frac = h.get("feedback_noise_frac")
    if not frac:
        return 0.0
    yf = np.asarray(y)[np.isfinite(y)]
    return float(frac) * float(np.percentile(yf, 99) - np.percentile(yf, 1)) if len(yf) else 0.0


def feedback_noise(shape: tuple[int, ...], sigma: float, gen: torch.Generator) -> torch.Tensor:
    """Errors of mixed size: sigma * N(0, 1) * U(0, 1), a quarter of them exactly zero (so the
    measured-force case stays in the training set)."""
    e = sigma * torch.randn(shape, generator=gen) * torch.rand(shape, generator=gen)
    return e * (torch.rand(shape, generator=gen) > 0.25)


class InputScaler(nn.Module):
    def __init__(self, features: tuple[str, ...], x: np.ndarray) -> None:
        super().__init__()
        soft = np.array([f in RATIO_DIVISORS for f in features])
        s = np.ones(len(features))
        for j in np.flatnonzero(soft):
            med = float(np.median(np.abs(x[:, j])))
            s[j] = med if med > 0 else 1.0
        z = np.where(soft, np.arcsinh(np.clip(x / s, -ASINH_CLIP, ASINH_CLIP)), x)
        mu = z.mean(axis=0)
        sd = z.std(axis=0)
        sd[sd == 0] = 1.0
        self.register_buffer("soft", torch.tensor(soft))
        self.register_buffer("s", torch.tensor(s, dtype=torch.float32))
        self.register_buffer("mu", torch.tensor(mu, dtype=torch.float32))
        self.register_buffer("sd", torch.tensor(sd, dtype=torch.float32))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # asinh written out: the TorchScript exporter has no symbolic for aten::asinh. The
        # clip keeps u*u finite in float32 (a velocity of 1e-20 m/s makes F/v ~ 1e20); asinh
        # is ~35 there and flat, so nothing is lost.
        u = torch.clamp(x / self.s, -ASINH_CLIP, ASINH_CLIP)
        asinh = torch.sign(u) * torch.log(torch.abs(u) + torch.sqrt(u * u + 1.0))
        z = torch.where(self.soft, asinh, x)
        return (z - self.mu) / self.sd


class TargetScaler(nn.Module):
    """y = offset + scale * output (standardisation, or min-max for a sigmoid output)."""

    def __init__(self, offset: float, scale: float) -> None:
        super().__init__()
        self.register_buffer("offset", torch.tensor(offset, dtype=torch.float32))
        self.register_buffer("scale", torch.tensor(scale, dtype=torch.float32))

    def forward(self, out: torch.Tensor) -> torch.Tensor:
        return out * self.scale + self.offset

    def encode(self, y: np.ndarray) -> np.ndarray:
        return (y - float(self.offset)) / float(self.scale)


class DenseNet(nn.Module):
    def __init__(self, inp: InputScaler, body: nn.Module, out: TargetScaler) -> None:
        super().__init__()
        self.inp, self.body, self.out = inp, body, out

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        return self.out(self.body(self.inp(features)))


DNN_DEFAULT = {
    "arch": "mlp",
    "hidden": [128, 128, 64],
    "activation": "silu",
    "dropout": 0.0,
    "optimizer": "adam",
    "lr": 1e-3,
    # None: at least 20 epochs and at least `min_updates` optimizer steps, so that a small
    # dataset (a few hundred rows of a 50 Hz import: one batch per epoch) is trained as long
    # as the bench's (~150 batches per epoch); a number is taken as given
    "epochs": None,
    "min_updates": 3000,
    "batch": 2048,
    "loss": "mse",
    "feedback_noise": 0.0,
}
#: thesis: 150 sigmoid - dropout 0.2 - 25 tanh - dropout 0.2 - 1 sigmoid, MSE, lr 1e-6
DNN_THESIS = {
    "arch": "thesis",
    "hidden": [150, 25],
    "dropout": 0.2,
    "optimizer": "adam",
    "lr": 1e-6,
    "epochs": 30,
    "batch": 32,
    "loss": "mse",
}

_ACT = {"silu": nn.SiLU, "tanh": nn.Tanh, "relu": nn.ReLU, "sigmoid": nn.Sigmoid}


def _loss(name: str) -> nn.Module:
    return {"mse": nn.MSELoss(), "mae": nn.L1Loss()}[name]


def _optim(name: str, params: object, lr: float) -> torch.optim.Optimizer:
    if name == "sgd":
        return torch.optim.SGD(params, lr=lr)
    return torch.optim.Adam(params, lr=lr)


class DenseModel(ForceModel):
    """Rows layout, with `aux` [n, 4] (`AUX` of the same rows) when the previous force is
    perturbed (feedback noise). Fitted attribute: `net_`, the network with its scalers."""

    algo = "dnn"
    aux_columns = AUX
    defaults = DNN_DEFAULT
    _legacy_fitted = ("net",)

    def _build(self, x: np.ndarray, y: np.ndarray) -> DenseNet:
        h = self.hyper
        inp = InputScaler(self.features, x)
        n = len(self.features)
        if h["arch"] == "thesis":
            # Sigmoid output: the target is min-max scaled into [0, 1] (inside the graph).
            lo, hi = float(y.min()), float(y.max())
            out = TargetScaler(lo, max(hi - lo, 1e-9))
            body = nn.Sequential(
                nn.Linear(n, 150), nn.Sigmoid(), nn.Dropout(h["dropout"]),
                nn.Linear(150, 25), nn.Tanh(), nn.Dropout(h["dropout"]),
                nn.Linear(25, 1), nn.Sigmoid(),
            )  # fmt: skip
        else:
            out = TargetScaler(float(y.mean()), float(y.std()) or 1.0)
            layers: list[nn.Module] = []
            prev = n
            for w in h["hidden"]:
                layers += [nn.Linear(prev, int(w)), _ACT[h["activation"]]()]
                if h["dropout"]:
                    layers.append(nn.Dropout(h["dropout"]))
                prev = int(w)
            layers.append(nn.Linear(prev, 1))
            body = nn.Sequential(*layers)
        return DenseNet(inp, body, out)

    def fit(self, X: np.ndarray, y: np.ndarray, aux: np.ndarray | None = None) -> DenseModel:
        x, y = check_rows(X, y, len(self.features))
        h = self.hyper
        sigma = resolve_feedback_noise(h, y)
        noisy = sigma > 0 and any(f in PREVIOUS_FORCE_FEATURES for f in self.features)
        _aux_for(self, aux, noisy)
        torch.manual_seed(self.seed)
        net = self._build(x, y)
        xt = torch.tensor(x, dtype=torch.float32)
        if noisy:
            auxt = torch.tensor(check_rows(aux, y, len(AUX))[0], dtype=torch.float32)
        yt = torch.tensor(net.out.encode(y), dtype=torch.float32).unsqueeze(1)
        # Pre-scale once: the scaler is fixed, only the body learns.
        with torch.no_grad():
            zt = net.inp(xt)
        opt = _optim(h["optimizer"], net.body.parameters(), h["lr"])
        batch = int(h["batch"])
        per_epoch = math.ceil(len(y) / batch)
        if h.get("epochs") is None:
            epochs = max(20, math.ceil(int(h.get("min_updates", 0)) / per_epoch))
        else:
            epochs = int(h["epochs"])
        steps = epochs * per_epoch
        sched = (
            torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
            if h["arch"] != "thesis"
            else None
        )
        lossf = _loss(h["loss"])
        gen = torch.Generator().manual_seed(self.seed)
        t0 = time.perf_counter()
        net.train()
        losses = []
        bar = tqdm(range(epochs), desc=f"{self.name} epochs", disable=not self.progress)
        for _ in bar:
            perm = torch.randperm(len(y), generator=gen)
            total = 0.0
            for i in range(0, len(y), batch):
                idx = perm[i : i + batch]
                if noisy:
                    # Feedback-noise training: the previous force inside the features is
                    # corrupted, the target is not, so the network learns to pull an erroneous
                    # previous force back towards the truth: a contraction, which keeps its
                    # closed loop (own predictions fed back) from drifting.
                    with torch.no_grad():
                        e = feedback_noise((len(idx),), sigma, gen)
                        zb = net.inp(perturb_previous_force(xt[idx], self.features, auxt[idx], e))
                else:
                    zb = zt[idx]
                opt.zero_grad()
                loss = lossf(net.body(zb), yt[idx])
                loss.backward()
                opt.step()
                if sched is not None:
                    sched.step()
                total += loss.item() * len(idx)
            losses.append(total / len(y))
            bar.set_postfix(loss=f"{losses[-1]:.4g}")
            if not math.isfinite(losses[-1]):
                raise FloatingPointError(f"{self.name}: training loss became {losses[-1]}")
        net.eval()
        self.net_ = net
        self.n_features_in_ = x.shape[1]
        self.train_info_ = {
            "rows": int(len(y)),
            "epochs": epochs,
            "feedback_noise_n": sigma,
            "fit_seconds": round(time.perf_counter() - t0, 2),
            "final_train_loss_scaled": losses[-1],
        }
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        self._check_fitted()
        x = self._check_X(X)
        out = []
        with torch.no_grad():
            for i in range(0, len(x), 65536):
                xt = torch.tensor(x[i : i + 65536], dtype=torch.float32)
                out.append(self.net_(xt).numpy()[:, 0])
        return np.concatenate(out).astype(np.float64) if out else np.zeros(0)

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:DenseStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs), or with `fused=False` the multi-node graph (same folded weights)."""
        self._check_fitted()
        build = dense_fused if fused else dense_graph
        return build(self.net_.eval(), len(self.features), ASINH_CLIP)


class LSTMNet(nn.Module):
    def __init__(self, inp: InputScaler, hidden: int, out: TargetScaler) -> None:
        super().__init__()
        self.inp = inp
        self.lstm = nn.LSTM(len(inp.mu), hidden, batch_first=True)
        self.head = nn.Linear(hidden, 1)
        self.out = out

    def forward_scaled(
        self, z: torch.Tensor, state: tuple[torch.Tensor, torch.Tensor] | None
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        y, st = self.lstm(z, state)
        return self.head(y), st


LSTM_DEFAULT = {
    "hidden": 100,
    "lr": 1e-3,
    "loss": "mse",
    # Many short streams: on a CPU the cost of back-propagation through an LSTM grows with the
    # chunk length (sequential) far more than with the batch, and the state is carried across
    # chunks anyway.
    "streams": 256,
    # The truncated-BPTT window in seconds (the object's time constants are seconds), turned
    # into steps at the recordings' row rate and capped at `max_chunk` steps to bound the
    # sequential cost: 50 steps are 1 s of a 50 Hz import but 5 ms of the 10 kHz bench (the
    # effective horizon is in the training info).
    "horizon_s": 1.0,
    "max_chunk": 50,
    "iterations": 600,
    "optimizer": "adam",
    "feedback_noise": 0.0,
}
#: thesis: 100 units + dense 1, MAE loss, learning rate 1e-6
LSTM_THESIS = {**LSTM_DEFAULT, "lr": 1e-6, "loss": "mae"}


class LSTMModel(ForceModel):
    """LSTM stepped at the loop rate, trained by truncated back-propagation through time.

    Serving steps the LSTM once per control step and carries its state indefinitely, so
    training does the same: `streams` parallel cursors walk through the loop-rate training
    recordings in consecutive `chunk`-step pieces, carrying (detached) state from chunk to
    chunk; a cursor that reaches the end of its recording restarts at a random place with zero
    state. Rows are never decimated here (the state's time step must be the loop's).

    Sequences layout: `fit(X, y, info, aux=None)`, X a list of [n_i, f] sequences (one per
    recording, every row), y their [n_i] targets, `info` their `SequenceInfo` (row rate: the
    chunk in steps; stride: the rows the input and target scalers are fitted on, as a
    stateless model's), `aux` one [n_i, 4] array (`AUX`) per sequence when the previous force
    is perturbed. Fitted attribute: `net_`, the network with its scalers.
    """

    algo = "lstm"
    kind = "stateful"
    layout = "sequences"
    aux_columns = AUX
    defaults = LSTM_DEFAULT
    _legacy_fitted = ("net",)

    def fit(
        self,
        X: list[np.ndarray],
        y: list[np.ndarray],
        info: list[SequenceInfo],
        aux: list[np.ndarray] | None = None,
    ) -> LSTMModel:
        seqs, targets = check_sequences(X, y, len(self.features), len(info))
        torch.manual_seed(self.seed)
        rng = np.random.default_rng(self.seed)
        h = self.hyper
        nf = len(self.features)
        # the scalers' rows: every stride-th of each sequence, non-finite rows dropped
        xs = np.concatenate([x[:: i.stride] for x, i in zip(seqs, info, strict=True)])
        ys = np.concatenate([v[:: i.stride] for v, i in zip(targets, info, strict=True)])
        ok = np.isfinite(xs).all(axis=1) & np.isfinite(ys)
        xs, ys = xs[ok], ys[ok]
        sigma = resolve_feedback_noise(h, ys)
        noisy = sigma > 0 and any(f in PREVIOUS_FORCE_FEATURES for f in self.features)
        _aux_for(self, aux, noisy)
        gen = torch.Generator().manual_seed(self.seed)
        net = LSTMNet(
            InputScaler(self.features, xs), int(h["hidden"]),
            TargetScaler(float(ys.mean()), float(ys.std()) or 1.0),
        )  # fmt: skip
        steps = {i.row_step for i in info}
        if steps != {1}:
            # The served LSTM is stepped once per control step; rows k steps apart teach it a
            # k-times longer time step. Train on full-rate recordings (DECIMATE=1) for serving.
            warnings.warn(
                f"{self.name}: recordings have {sorted(steps)} control steps per row; the LSTM "
                "learns that time step, but is served once per control step",
                stacklevel=2,
            )
        series = []
        with torch.no_grad():
            for k, (xk, yk) in enumerate(zip(seqs, targets, strict=True)):
                yt = torch.tensor(net.out.encode(yk), dtype=torch.float32)
                if noisy:
                    # raw: scaled per batch after the perturbation
                    xa = np.column_stack([xk, np.asarray(aux[k], dtype=np.float64)])  # type: ignore[index]
                    series.append((torch.tensor(xa, dtype=torch.float32), yt))
                else:
                    xt = torch.tensor(xk, dtype=torch.float32)
                    series.append((torch.nan_to_num(net.inp(xt)), yt))
        lengths = np.array([len(s[1]) for s in series])
        rate = float(np.median([i.sample_rate_hz for i in info]))
        if "chunk" in h:  # an explicit step count (older models, or given)
            chunk = int(h["chunk"])
        else:
            chunk = max(2, min(int(h["max_chunk"]), round(float(h["horizon_s"]) * rate)))
        n_streams = int(h["streams"])
        if lengths.min() <= chunk + 1:
            raise ValueError(f"recordings shorter than one LSTM chunk ({chunk} steps)")

        def restart() -> tuple[int, int]:
            k = int(rng.choice(len(series), p=lengths / lengths.sum()))
            return k, int(rng.integers(0, lengths[k] - chunk))

        cursors = [restart() for _ in range(n_streams)]
        hid = int(h["hidden"])
        hs = torch.zeros(1, n_streams, hid)
        cs = torch.zeros(1, n_streams, hid)
        opt = _optim(h["optimizer"], net.parameters(), h["lr"])
        iters = int(h["iterations"])
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, iters) if h["lr"] >= 1e-4 else None
        lossf = _loss(h["loss"])
        t0 = time.perf_counter()
        losses = []
        bar = tqdm(range(iters), desc=f"{self.name} TBPTT", disable=not self.progress)
        for _ in bar:
            zb = torch.stack([series[k][0][p : p + chunk] for k, p in cursors])
            if noisy:
                # Feedback noise, as for the dense network, but one error per stream and chunk
                # (a closed-loop error drifts slowly rather than jumping every step).
                with torch.no_grad():
                    e = feedback_noise((len(cursors), 1), sigma, gen).expand(-1, chunk)
                    xb = perturb_previous_force(zb[..., :nf], self.features, zb[..., nf:], e)
                    zb = torch.nan_to_num(net.inp(xb))
            yb = torch.stack([series[k][1][p : p + chunk] for k, p in cursors]).unsqueeze(2)
            opt.zero_grad()
            pred, (hn, cn) = net.forward_scaled(zb, (hs, cs))
            loss = lossf(pred, yb)
            loss.backward()
            nn.utils.clip_grad_norm_(net.parameters(), 1.0)
            opt.step()
            if sched is not None:
                sched.step()
            hs, cs = hn.detach(), cn.detach()
            for i, (k, p) in enumerate(cursors):
                if p + 2 * chunk > lengths[k]:
                    cursors[i] = restart()
                    hs[:, i] = 0.0
                    cs[:, i] = 0.0
                else:
                    cursors[i] = (k, p + chunk)
            losses.append(loss.item())
            if len(losses) % 50 == 0:
                bar.set_postfix(loss=f"{np.mean(losses[-50:]):.4g}")
        net.eval()
        self.net_ = net
        self.n_features_in_ = nf
        self.train_info_ = {
            "row_step": sorted(steps),
            "steps_seen": iters * n_streams * chunk,
            "chunk_steps": chunk,
            "horizon_s_effective": chunk / rate,
            "feedback_noise_n": sigma,
            "fit_seconds": round(time.perf_counter() - t0, 2),
            "final_train_loss_scaled": float(np.mean(losses[-50:])),
        }
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """Runs the rows as one sequence in order from zero state (one-step: recorded inputs)."""
        self._check_fitted()
        x = self._check_X(X)
        net = self.net_
        out = []
        state = None
        with torch.no_grad():
            for i in range(0, len(x), 50_000):
                z = net.inp(torch.tensor(x[i : i + 50_000], dtype=torch.float32)).unsqueeze(0)
                y, state = net.forward_scaled(z, state)
                out.append(net.out(y)[0, :, 0].numpy())
        return np.concatenate(out).astype(np.float64) if out else np.zeros(0)

    def to_onnx(self, fused: bool = True) -> onnx.ModelProto:
        """One `ai.haptics:LstmStep` node (the fused operator: needs libhaptics_fused_ops.so
        where it runs), or with `fused=False` the multi-node graph (ONNX's LSTM op; same
        state)."""
        self._check_fitted()
        build = lstm_fused if fused else lstm_graph
        return build(self.net_.eval(), len(self.features), ASINH_CLIP)

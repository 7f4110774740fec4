"""`lawfree`'s network readout: a small network in place of (or on top of) the linear readout,
reading the same memory.

Why: `lawfree`'s readout is linear in its weights (functions of the depth times each memory
term, lawfree.py). A law whose memory relaxes at a rate set by the force it carries (an Eyring
dashpot, a sinh of the stress: the Hunt-Crossley object; nonlinear viscoelasticity in general)
is outside it: on the leave-one-rate-out folds `lawfree` stayed 0.98-2.3x of sd_poly2 there.
Read through two tanh layers, the same memory came 1.3-1.9x closer on all three Hunt-Crossley
folds, and within 7 % elsewhere but one fold (docs/laws.md, "A network readout on
`lawfree`'s memory"; the prototype that measured it, since retired, is `git show
0552afc:scripts/lawfree-mlp-readout.py`). So `haptics-train train` tries it on `lawfree`'s
validated choice and keeps it only where validation prefers it clearly
(`lawfree_selection.try_network_readout`): a network extrapolates differently from the linear
readout (it saturates where the linear readout goes on linearly past the deepest training
press), and only a validation recording can say which a law needs.

The network (the memory itself is the fitted `lawfree`'s, unchanged):

    q' = [q, w]                               the readout's inputs and w = min(u, 1)
    g  = w3 . tanh(W2 tanh(W1 q' + b1) + b2) + b3
    object = max(0, g + (linear readout if residual else 0)) x (x > 0)

with the inputs' standardisation and the target's scale folded into W1, b1, w3, b3, so the
served step is three matrix products and two tanh. Trained on the training rows in contact
where the probe slides (the rows the linear readout is fitted on) against the target less the
bench's friction the linear fit identified (`alone`), or less the linear readout's force too
(`residual`): Adam, mini-batches of `NET_BATCH`, weight decay, at most `NET_MAX_ROWS` rows
(evenly spaced) and `NET_MAX_STEPS` steps. Every `NET_EVAL_EPOCHS` epochs the model is scored
over every row of the validation recordings (at most `NET_MAX_VALIDATION_ROWS` of them, evenly
spaced) and the best epoch is kept: the training length is a choice made on validation, as the
width, the weight decay and the mode are (`NET_GRID`). The test recordings play no part.
"""

from __future__ import annotations

import copy
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from .structured import dahl

if TYPE_CHECKING:
    from .lawfree import LawFreeModel

#: (mode, hidden width, weight decay): the prototype's grid, where it was measured. Two widths
#: a factor 2 apart and two decays a decade apart bracket what it chose on the twelve folds.
NET_GRID: tuple[tuple[str, int, float], ...] = tuple(
    itertools.product(("alone", "residual"), (16, 32), (1e-4, 1e-3))
)
NET_BATCH = 256
NET_LEARNING_RATE = 3e-3
#: the prototype's 1500 epochs of a testing machine's few thousand rows are ~15 000 steps; the
#: bench's datasets hold 100x the rows, so the steps are capped and the rows evenly thinned
NET_EPOCHS = 1500
NET_MAX_STEPS = 15_000
NET_MAX_ROWS = 20_000
NET_EVAL_EPOCHS = 10
NET_MAX_VALIDATION_ROWS = 50_000


@dataclass(frozen=True)
class NetReadout:
    """A fitted network readout (standardisation folded in): what `LawFreeModel` predicts
    with and the ONNX graph and the fused operator carry."""

    w1: np.ndarray  # [H, n + 1]
    b1: np.ndarray  # [H]
    w2: np.ndarray  # [H, H]
    b2: np.ndarray  # [H]
    w3: np.ndarray  # [H]
    b3: float
    residual: bool
    hidden: int
    weight_decay: float
    epoch: int
    validation_rmse_n: float

    def __call__(self, qw: np.ndarray) -> np.ndarray:
        """g for rows of q' = [q, w] ([n, inputs + 1])."""
        h = np.tanh(qw @ self.w1.T + self.b1)
        h = np.tanh(h @ self.w2.T + self.b2)
        return h @ self.w3 + self.b3

    def describe(self) -> dict:
        return {"mode": "residual" if self.residual else "alone", "hidden": self.hidden,
                "weight_decay": self.weight_decay, "epoch": self.epoch,
                "validation_every_row_rmse_n": self.validation_rmse_n}  # fmt: skip


def with_w(z: np.ndarray) -> np.ndarray:
    """q' = [q, min(u, 1)] from the readout's inputs q (u first)."""
    return np.column_stack([z, np.minimum(z[:, :1], 1.0)])


@dataclass
class Rows:
    """One set of rows as the network sees them: q', the linear readout's object force before
    the clamp, what the object must add to the bench's friction (the target less it), and
    where the object is in contact."""

    qw: np.ndarray
    linear: np.ndarray
    target: np.ndarray
    contact: np.ndarray

    @staticmethod
    def of(model: LawFreeModel, x: np.ndarray, v: np.ndarray, t: np.ndarray, dt: float) -> Rows:
        z, contact = model._inputs(x, v, dt)  # noqa: SLF001
        bench = sum(c * dahl(x, L) for c, L in zip(model.c_, model.hyper["friction_lengths_m"],
                                                   strict=True))  # fmt: skip
        return Rows(with_w(z), model.linear_object(z), t - bench, contact)

    def take(self, rows: np.ndarray) -> Rows:
        return Rows(self.qw[rows], self.linear[rows], self.target[rows], self.contact[rows])


def evenly(n: int, most: int) -> np.ndarray:
    """At most `most` of n row indices, evenly spaced (all of them when n <= most)."""
    return np.arange(n) if n <= most else np.linspace(0, n - 1, most).round().astype(int)


def training_rows(model: LawFreeModel, X: list[np.ndarray], y: list[np.ndarray],
                  info: list) -> Rows:  # fmt: skip
    """The rows the linear readout was fitted on (`LawFreeModel.fit_rows`), in contact, pooled
    and evenly thinned to `NET_MAX_ROWS`."""
    parts = []
    for x, v, t, keep, dt in model.fit_rows(X, y, info):
        r = Rows.of(model, x, v, t, dt)
        parts.append(r.take(keep & r.contact))
    pooled = Rows(*(np.concatenate([getattr(p, f) for p in parts])
                    for f in ("qw", "linear", "target", "contact")))  # fmt: skip
    if len(pooled.target) == 0:
        raise ValueError("lawfree network readout: no training row in contact")
    return pooled.take(evenly(len(pooled.target), NET_MAX_ROWS))


def validation_rows(model: LawFreeModel, recs: list[tuple[np.ndarray, np.ndarray, float]]) -> Rows:
    """Every row of the validation recordings ((x v [n, 2], target, period) each, stepped at
    its own period as evaluation steps it), pooled and evenly thinned to
    `NET_MAX_VALIDATION_ROWS`."""
    parts = [Rows.of(model, xv[:, 0], xv[:, 1], t, dt) for xv, t, dt in recs]
    pooled = Rows(*(np.concatenate([getattr(p, f) for p in parts])
                    for f in ("qw", "linear", "target", "contact")))  # fmt: skip
    return pooled.take(evenly(len(pooled.target), NET_MAX_VALIDATION_ROWS))


def object_force(rows: Rows, g: np.ndarray, residual: bool) -> np.ndarray:
    """The rendered object: max(0, g (+ the linear readout)) in contact, 0 out of it."""
    f = g + rows.linear if residual else g
    return np.where(rows.contact, np.maximum(f, 0.0), 0.0)


def train_net(train: Rows, valid: Rows, mode: str, hidden: int, weight_decay: float,
              seed: int = 0, max_steps: int = NET_MAX_STEPS) -> NetReadout:  # fmt: skip
    """One network of the grid, its epoch chosen on `valid` (every row's RMSE of the object
    against the target less the bench's friction: the free run's error, the friction being
    the linear fit's in both)."""
    import torch  # the heavy import only where a network is trained

    residual = mode == "residual"
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    t = train.target - train.linear if residual else train.target
    mu, sd = train.qw.mean(0), train.qw.std(0) + 1e-9
    ts = float(np.abs(t).max()) or 1.0
    n_in = train.qw.shape[1]
    with torch.random.fork_rng():
        torch.set_num_threads(1)
        net = torch.nn.Sequential(
            torch.nn.Linear(n_in, hidden), torch.nn.Tanh(),
            torch.nn.Linear(hidden, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 1),
        ).double()  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=NET_LEARNING_RATE, weight_decay=weight_decay)
    zt = torch.tensor((train.qw - mu) / sd)
    tt = torch.tensor(t / ts)
    zv = torch.tensor((valid.qw - mu) / sd)
    per_epoch = max(1, -(-len(zt) // NET_BATCH))
    epochs = max(1, min(NET_EPOCHS, max_steps // per_epoch))
    best: tuple[float, dict | None, int] = (np.inf, None, 0)
    for ep in range(epochs):
        perm = torch.randperm(len(zt), generator=gen)
        for i in range(0, len(zt), NET_BATCH):
            b = perm[i : i + NET_BATCH]
            opt.zero_grad()
            loss = torch.mean((net(zt[b])[:, 0] - tt[b]) ** 2)
            loss.backward()
            opt.step()
        if ep % NET_EVAL_EPOCHS == NET_EVAL_EPOCHS - 1 or ep == epochs - 1:
            with torch.no_grad():
                g = net(zv)[:, 0].numpy() * ts
            e = float(np.sqrt(np.mean((object_force(valid, g, residual) - valid.target) ** 2)))
            if e < best[0]:
                best = (e, copy.deepcopy(net.state_dict()), ep + 1)
    assert best[1] is not None
    net.load_state_dict(best[1])
    l1, l2, l3 = net[0], net[2], net[4]
    w1 = l1.weight.detach().numpy()
    # standardisation folded into the first layer, the target's scale into the last
    return NetReadout(
        w1=w1 / sd, b1=l1.bias.detach().numpy() - (w1 / sd) @ mu,
        w2=l2.weight.detach().numpy().copy(), b2=l2.bias.detach().numpy().copy(),
        w3=l3.weight.detach().numpy()[0] * ts, b3=float(l3.bias.detach().numpy()[0]) * ts,
        residual=residual, hidden=hidden, weight_decay=weight_decay, epoch=best[2],
        validation_rmse_n=best[0],
    )  # fmt: skip


def fit_network_readout(
    model: LawFreeModel, X: list[np.ndarray], y: list[np.ndarray], info: list,
    validation: list[tuple[np.ndarray, np.ndarray, float]], seed: int = 0,
    grid: tuple[tuple[str, int, float], ...] = NET_GRID, log: object = None,
    max_steps: int = NET_MAX_STEPS,
) -> tuple[LawFreeModel, dict[str, float]]:  # fmt: skip
    """Every network of `grid` on fitted `model`'s memory, each trained for at most
    `max_steps` mini-batches; returns (a copy of `model` reading through the one with the
    lowest validation RMSE, each candidate's RMSE by label). `log`: a callable taking one line
    per candidate."""
    train = training_rows(model, X, y, info)
    valid = validation_rows(model, validation)
    scores: dict[str, float] = {}
    best: NetReadout | None = None
    for mode, hidden, wd in grid:
        net = train_net(train, valid, mode, hidden, wd, seed, max_steps)
        label = f"{mode}, {hidden} wide, decay {wd:g}"
        scores[label] = net.validation_rmse_n
        if callable(log):
            log(f"{label}: validation every-row RMSE {net.validation_rmse_n:.4f} N "
                f"(epoch {net.epoch})")  # fmt: skip
        if best is None or net.validation_rmse_n < best.validation_rmse_n:
            best = net
    assert best is not None
    out = copy.deepcopy(model)
    out.net_ = best
    out.train_info_ = {**model.train_info_, "network_readout": best.describe()}
    return out, scores

#!/usr/bin/env python3
"""A prototype, not product code: would `lawfree` gain from a nonlinear readout?

`lawfree` reads its memory (fading-memory filters and play operators of the compression, the
irreversible memory where kept) through a readout that is linear in its weights: functions of
the depth times each memory term. A law whose relaxation depends on the force it carries (the
Eyring dashpot of the Hunt-Crossley generator, a sinh of the stress) is outside that readout.
This script keeps the memory exactly as each fold's fitted `lawfree` computes it, and puts a
small network (two tanh layers) in place of the linear readout, on the leave-one-rate-out folds
of `python -m haptics_train.loro`:

- inputs: `LawFreeModel._inputs` (the readout's inputs q) and w = min(u, 1), standardised on
  the training rows; target: the recorded force on the training rows in contact;
- trained with Adam (mini-batches of 256, learning rate 3e-3) and weight decay; the output is
  rendered as `lawfree`'s: 0 out of contact, never below 0. With nothing fed back the free run
  is the prediction itself;
- chosen on the fold's validation tests only: hidden width (16, 32), weight decay (1e-4,
  1e-3), the network alone or on top of the linear readout (fitted to its residual), and the
  epoch (every 10th of `--epochs`, the lowest validation RMSE kept); the held-out rate is
  scored once, with the choice made.

Usage (after `python -m haptics_train.loro --generator NAME --models sd_poly2,lawfree
--work DIR`, which leaves each fold's models in DIR/fold_rate_*/models):

    scripts/lawfree-mlp-readout.py DIR [--epochs 1500] [--seed 0]

Prints every candidate's validation and held-out RMSE (N) per fold, then per fold one JSON
line; writes DIR/mlp-readout.json. One CPU thread (torch), about 90 s a fold here.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import joblib
import numpy as np
import torch
from haptics_train.data import load_manifest, to_sequences

#: (readout inputs [n, k], contact mask, target, the linear lawfree's prediction) per recording
Part = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def parts(model: object, recs: list) -> list[Part]:
    """Each recording as the fitted `lawfree` sees it: its readout's inputs (plus w) and its
    own prediction (the linear readout, bench friction included, as the free run scores it)."""
    xs, ys, _ = to_sequences(recs, ["position_x", "velocity"], decimate=None)
    out = []
    for xv, t in zip(xs, ys, strict=True):
        z, contact = model._inputs(xv[:, 0], xv[:, 1], model.dt_)  # noqa: SLF001
        w = np.minimum(z[:, :1], 1.0)
        out.append((np.column_stack([z, w]), contact, t, model.predict(xv)))
    return out


def rmse(ps: list[Part], preds: list[np.ndarray]) -> float:
    """Pooled RMSE over every row of the recordings (N)."""
    e = np.concatenate([p - t for (_, _, t, _), p in zip(ps, preds, strict=True)])
    return float(np.sqrt(np.mean(e**2)))


def fit(tr: list[Part], va: list[Part], hidden: int, wd: float, resid: bool, epochs: int,
        seed: int) -> tuple[float, int, object]:  # fmt: skip
    """Trains one network; returns (its best validation RMSE, that epoch, a predictor)."""
    torch.manual_seed(seed)
    z = np.concatenate([q[c] for q, c, _, _ in tr])
    t = np.concatenate([(y - p * resid)[c] for _, c, y, p in tr])
    mu, sd = z.mean(0), z.std(0) + 1e-9
    ts = float(np.abs(t).max()) or 1.0
    net = torch.nn.Sequential(
        torch.nn.Linear(z.shape[1], hidden), torch.nn.Tanh(),
        torch.nn.Linear(hidden, hidden), torch.nn.Tanh(), torch.nn.Linear(hidden, 1),
    )  # fmt: skip
    opt = torch.optim.Adam(net.parameters(), lr=3e-3, weight_decay=wd)
    zt = torch.tensor((z - mu) / sd, dtype=torch.float32)
    tt = torch.tensor(t / ts, dtype=torch.float32)

    def predict(ps: list[Part]) -> list[np.ndarray]:
        with torch.no_grad():
            out = []
            for q, c, _, p in ps:
                f = net(torch.tensor((q - mu) / sd, dtype=torch.float32)).numpy()[:, 0] * ts
                out.append(np.where(c, np.maximum(f + p * resid, 0.0), 0.0))
            return out

    best: tuple[float, dict | None, int] = (np.inf, None, 0)
    for ep in range(epochs):
        perm = torch.randperm(len(zt))
        for i in range(0, len(zt), 256):
            b = perm[i : i + 256]
            opt.zero_grad()
            loss = torch.mean((net(zt[b])[:, 0] - tt[b]) ** 2)
            loss.backward()
            opt.step()
        if ep % 10 == 9:
            v = rmse(va, predict(va))
            if v < best[0]:
                best = (v, {k: x.clone() for k, x in net.state_dict().items()}, ep + 1)
    assert best[1] is not None, "no validation score (epochs < 10)"
    net.load_state_dict(best[1])
    return best[0], best[2], predict


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("work", type=Path)
    ap.add_argument("--epochs", type=int, default=1500)
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()
    torch.set_num_threads(1)
    folds = sorted(a.work.glob("fold_rate_*"))
    if not folds:
        raise SystemExit(f"{a.work}: no fold_rate_* folders (run python -m haptics_train.loro)")
    res = {}
    for fold in folds:
        ds = load_manifest(fold / "dataset.toml")
        model = joblib.load(fold / "models" / "lawfree.joblib")["model"]
        tr, va, te = parts(model, ds.train), parts(model, ds.validation), parts(model, ds.test)
        cands = []
        for resid in (False, True):
            for hidden in (16, 32):
                for wd in (1e-4, 1e-3):
                    v, ep, predict = fit(tr, va, hidden, wd, resid, a.epochs, a.seed)
                    held = rmse(te, predict(te))
                    cands.append((v, hidden, wd, ep, resid, held))
                    print(f"  {fold.name} residual={resid} hidden={hidden} decay={wd:g}: "
                          f"validation {v:.4f} (epoch {ep}), held out {held:.4f}",
                          flush=True)  # fmt: skip
        v, hidden, wd, ep, resid, held = min(cands, key=lambda c: c[0])
        res[fold.name] = {
            "lawfree_validation": rmse(va, [p for *_, p in va]),
            "lawfree_test": rmse(te, [p for *_, p in te]),
            "mlp_validation": v,
            "mlp_test": held,
            "choice": {"hidden": hidden, "weight_decay": wd, "epoch": ep, "residual": resid},
        }
        print(fold.name, json.dumps(res[fold.name]), flush=True)
    (a.work / "mlp-readout.json").write_text(json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

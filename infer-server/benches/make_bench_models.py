"""Writes the benchmark models: the three model families the thesis compares, at its sizes.

Usage: make_bench_models.py OUT_DIR

- rf.onnx: scikit-learn RandomForestRegressor, 100 trees, max_depth 9, via skl2onnx
  (ai.onnx.ml opset 3, TreeEnsembleRegressor);
- dense.onnx: the thesis's dense network, 9 -> 150 -> 25 -> 1 (ReLU), via torch.onnx.export;
- lstm.onnx: an LSTM of 100 units stepped one sample at a time (h/c in and out), then a linear
  head, via torch.onnx.export (dynamo=False).

All take the nine features in Table 3.1 order and follow docs/model-contract.md (names,
shapes, metadata). Weights are trained or drawn from a fixed seed; latency does not depend on
their values, only on the model's structure.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import onnx

from haptics_train.vocab import THESIS_FEATURES

#: The nine features of thesis Table 3.1: the vocabulary's (train/'s generated vocab.py).
FEATURES = list(THESIS_FEATURES)
N = len(FEATURES)


def set_meta(
    model: onnx.ModelProto, kind: str, name: str, extra: dict[str, str] | None = None
) -> None:
    props = {
        "haptics.features": ",".join(FEATURES),
        "haptics.kind": kind,
        "haptics.units": "N",
        "haptics.provenance": json.dumps(
            {"model": name, "trainer": "infer-server benches", "seed": 0}
        ),
    }
    props.update(extra or {})
    del model.metadata_props[:]
    for k, v in props.items():
        entry = model.metadata_props.add()
        entry.key = k
        entry.value = v


def synthetic(rows: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    x = rng.uniform(-1.0, 1.0, size=(rows, N)).astype(np.float32)
    y = (
        3.0 * np.sin(2.0 * x[:, 0])
        + x[:, 1] * x[:, 3]
        + 0.5 * x[:, 2] ** 2
        + np.where(x[:, 4] > 0.2, 1.0, -1.0)
        + 0.1 * rng.standard_normal(rows)
    ).astype(np.float32)
    return x, y


def write_rf(out: Path) -> None:
    from skl2onnx import to_onnx
    from skl2onnx.common.data_types import FloatTensorType
    from sklearn.ensemble import RandomForestRegressor

    rng = np.random.default_rng(0)
    x, y = synthetic(20_000, rng)
    rf = RandomForestRegressor(n_estimators=100, max_depth=9, random_state=0, n_jobs=1)
    rf.fit(x, y)
    model = to_onnx(
        rf,
        initial_types=[("features", FloatTensorType([None, N]))],
        final_types=[("force", FloatTensorType([None, 1]))],
        target_opset={"": 17, "ai.onnx.ml": 3},
    )
    set_meta(model, "stateless", "rf")
    onnx.save(model, str(out / "rf.onnx"))


def write_torch(out: Path) -> None:
    import torch
    from torch import nn

    torch.manual_seed(0)

    class Dense(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.net = nn.Sequential(
                nn.Linear(N, 150), nn.ReLU(), nn.Linear(150, 25), nn.ReLU(), nn.Linear(25, 1)
            )

        def forward(self, features: torch.Tensor) -> torch.Tensor:
            return self.net(features)

    dense = Dense().eval()
    torch.onnx.export(
        dense,
        (torch.zeros(1, N),),
        str(out / "dense.onnx"),
        input_names=["features"],
        output_names=["force"],
        dynamic_axes={"features": {0: "N"}, "force": {0: "N"}},
        opset_version=17,
        dynamo=False,
    )
    m = onnx.load(str(out / "dense.onnx"))
    set_meta(m, "stateless", "dnn")
    onnx.save(m, str(out / "dense.onnx"))

    hidden = 100

    class Stepped(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.lstm = nn.LSTM(N, hidden, batch_first=False)
            self.head = nn.Linear(hidden, 1)

        def forward(
            self, features: torch.Tensor, h_in: torch.Tensor, c_in: torch.Tensor
        ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
            y, (h, c) = self.lstm(features.unsqueeze(0), (h_in, c_in))  # [1, 1, n] seq-first
            return self.head(y[0]), h, c

    lstm = Stepped().eval()
    torch.onnx.export(
        lstm,
        (torch.zeros(1, N), torch.zeros(1, 1, hidden), torch.zeros(1, 1, hidden)),
        str(out / "lstm.onnx"),
        input_names=["features", "h_in", "c_in"],
        output_names=["force", "h_out", "c_out"],
        opset_version=17,
        dynamo=False,
    )
    m = onnx.load(str(out / "lstm.onnx"))
    set_meta(m, "stateful", "lstm", {"haptics.state_size": str(hidden)})
    onnx.save(m, str(out / "lstm.onnx"))


def main() -> int:
    if len(sys.argv) != 2:
        print(__doc__, file=sys.stderr)
        return 2
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    write_rf(out)
    write_torch(out)
    return 0


if __name__ == "__main__":
    sys.exit(main())

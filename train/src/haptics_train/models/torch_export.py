"""torch -> ONNX with the names and shapes of docs/model-contract.md (legacy exporter)."""

from __future__ import annotations

import io
import warnings

import onnx
import torch

OPSET = 17


def _export(module: torch.nn.Module, args: tuple, **kw: object) -> onnx.ModelProto:
    module = module.eval()
    buf = io.BytesIO()
    with warnings.catch_warnings():
        # The TorchScript exporter is deprecated but is the one that emits a plain ONNX LSTM
        # op with explicit state inputs, which is what the stateful contract needs.
        warnings.simplefilter("ignore")
        with torch.no_grad():
            torch.onnx.export(
                module, args, buf, dynamo=False, opset_version=OPSET, do_constant_folding=True, **kw
            )
    return onnx.load_from_string(buf.getvalue())


def export_stateless(module: torch.nn.Module, n_features: int) -> onnx.ModelProto:
    """Input `features` [N, n] float32 -> output `force` [N, 1] float32."""
    return _export(
        module,
        (torch.zeros(1, n_features, dtype=torch.float32),),
        input_names=["features"],
        output_names=["force"],
        dynamic_axes={"features": {0: "N"}, "force": {0: "N"}},
    )


def export_stateful(module: torch.nn.Module, n_features: int, hidden: int) -> onnx.ModelProto:
    """(`features` [1, n], `h_in`, `c_in` [1, 1, H]) -> (`force` [1, 1], `h_out`, `c_out`)."""
    z = torch.zeros(1, 1, hidden, dtype=torch.float32)
    return _export(
        module,
        (torch.zeros(1, n_features, dtype=torch.float32), z, z.clone()),
        input_names=["features", "h_in", "c_in"],
        output_names=["force", "h_out", "c_out"],
    )

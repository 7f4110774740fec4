"""Bench objects written as ONNX graphs (rt-loop's `law = "onnx"`, docs/laws/onnx.md): each
module builds one law's graph, steps the same law in numpy as its reference, and writes the
graph next to its material file."""

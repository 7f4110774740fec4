"""Reconstruction phase of the haptics pipeline: analysis, baselines, models, ONNX export."""

__version__ = "0.1.0"

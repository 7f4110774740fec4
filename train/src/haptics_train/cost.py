"""What a model costs per call, measured at export and written into its metadata
(`haptics.cost`, docs/model-contract.md).

ONNX Runtime runs the exported graph one sample at a time, as infer-server serves it: one
intra-op thread, all graph optimisations, inputs and outputs bound once (`run_with_iobinding`),
a stateful model's state fed back every step. The figures include Python's call overhead
(about 1 us: the one-node identity graph measures about 2 us here, against about 1 us in
infer-server), so they are an upper bound of what infer-server pays on the same machine;
infer-server measures its own warm-up again when it loads the model and warns when that
cannot meet the loop's deadline.
"""

from __future__ import annotations

import datetime as dt
import os
import platform
import time

import numpy as np
import onnx
import onnxruntime as ort

from .ort_ops import session_options_for

COST_KEY = "haptics.cost"
CALLS = 5000
WARM = 500


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def measure_cost(m: onnx.ModelProto, calls: int = CALLS) -> dict:
    """p50/p99/p99.9 of one call of `m` (us) on this machine; `calls` steps after a warm-up."""
    so = session_options_for(m)  # the fused operators registered (ort_ops.py)
    so.intra_op_num_threads = 1
    so.inter_op_num_threads = 1
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    sess = ort.InferenceSession(m.SerializeToString(), so, providers=["CPUExecutionProvider"])
    n = next(i for i in sess.get_inputs() if i.name == "features").shape[-1]
    feeds = {"features": np.zeros((1, int(n)), np.float32)}
    stateful = any(i.name == "h_in" for i in sess.get_inputs())
    binding = sess.io_binding()
    if stateful:
        shape = [int(d) for d in next(i for i in sess.get_inputs() if i.name == "h_in").shape]
        state = {k: ort.OrtValue.ortvalue_from_numpy(np.zeros(shape, np.float32))
                 for k in ("h_in", "c_in", "h_out", "c_out")}  # fmt: skip
        for k in ("h_in", "c_in"):
            binding.bind_ortvalue_input(k, state[k])
        for k in ("h_out", "c_out"):
            binding.bind_ortvalue_output(k, state[k])
    x = ort.OrtValue.ortvalue_from_numpy(feeds["features"])
    binding.bind_ortvalue_input("features", x)
    binding.bind_output("force")
    # a slow press of 0-10 mm (x, v and the rest small and moving), as the loop would feed it
    rows = np.zeros((WARM + calls, int(n)), np.float32)
    t = np.arange(WARM + calls) * 1e-4
    rows[:, 0] = 0.005 * (1 - np.cos(2 * np.pi * t))
    if n > 1:
        rows[:, 1] = 0.005 * 2 * np.pi * np.sin(2 * np.pi * t)
    times = np.empty(calls)
    buf = x.numpy()
    for i in range(WARM + calls):
        buf[...] = rows[i]
        x.update_inplace(buf)
        t0 = time.perf_counter_ns()
        sess.run_with_iobinding(binding)
        if i >= WARM:
            times[i - WARM] = time.perf_counter_ns() - t0
        if stateful:  # the state fed back (outside the timing: infer-server copies nothing)
            state["h_in"].update_inplace(state["h_out"].numpy())
            state["c_in"].update_inplace(state["c_out"].numpy())
    us = np.sort(times) / 1000.0
    q = lambda p: round(float(us[min(len(us) - 1, int(np.ceil(p * len(us))) - 1)]), 2)  # noqa: E731
    return {
        "p50_us": q(0.5),
        "p99_us": q(0.99),
        "p999_us": q(0.999),
        "calls": calls,
        "measured_by": f"onnxruntime {ort.__version__} (Python, one thread, run_with_iobinding)",
        "machine": f"{_cpu_model()}, {os.cpu_count()} CPUs",
        "load_average": [round(v, 2) for v in os.getloadavg()],
        "measured": dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
    }

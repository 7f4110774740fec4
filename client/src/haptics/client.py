"""`Client`: the running system (infer-server's gRPC control plane, `haptics.v1`) from Python.

The messages are the generated ones (`haptics.v1.haptics_pb2`, compiled from the repository's
.proto at install time): `status()` returns a `Status`, `models()` a list of `ModelInfo`, the
telemetry yields `TelemetrySample`s. docs/python.md describes every call."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

import grpc
from google.protobuf.message import Message

from . import connection
from .errors import (
    ACTIVATE_MODEL_CODES,
    LOAD_MODEL_CODES,
    BadModel,
    HapticsError,
    NotReachable,
    UploadRefused,
    from_rpc,
)
from .telemetry import Telemetry, is_repeated, to_columns
from .v1 import haptics_pb2 as pb
from .v1 import haptics_pb2_grpc as rpc

T = TypeVar("T")

#: The experiments `start_experiment` accepts (the loop refuses any other kind).
EXPERIMENTS = ("abstraction", "reproduction", "shadow", "position-replay")
#: The page's telemetry buckets: 10 loop steps (1 ms at 10 kHz), docs/web-protocol.md.
PAGE_DECIMATION = 10
_MAX_MESSAGE = 64 << 20


@dataclass(frozen=True)
class Swap:
    """A model swap: the model now active, the first loop step it answered, and what the
    server says the user should know about it (e.g. its training features were computed with
    other filters than the loop's: served anyway)."""

    model: pb.ModelInfo
    effective_step: int
    warnings: tuple[str, ...] = ()


class Client:
    """A connection to infer-server.

    `Client()` finds a local system by itself (docs/python.md, "Finding the system");
    `Client(address="host:50051", token="...")` names one. Raises NotReachable when nothing
    answers within `connect_timeout` seconds."""

    def __init__(
        self,
        address: str | None = None,
        token: str | None = None,
        *,
        instance: str | None = None,
        connect_timeout: float = 3.0,
    ) -> None:
        self.info = connection.resolve(address, token, instance)
        self.address = self.info.address
        target = self.address.split("://", 1)[1].rstrip("/")
        self._channel = grpc.insecure_channel(
            target,
            options=[
                ("grpc.max_send_message_length", _MAX_MESSAGE),
                ("grpc.max_receive_message_length", _MAX_MESSAGE),
            ],
        )
        try:
            grpc.channel_ready_future(self._channel).result(timeout=connect_timeout)
        except grpc.FutureTimeoutError:
            self._channel.close()
            raise NotReachable(
                f"cannot reach infer-server at {self.address} (address from "
                f"{self.info.address_from}) within {connect_timeout:g} s. Is it running? "
                "(scripts/up.sh starts it; or pass address=... / set HAPTICS_ADDR)"
            ) from None
        self._metadata = (
            (("authorization", f"Bearer {self.info.token}"),) if self.info.token else ()
        )
        self._models = rpc.ModelServiceStub(self._channel)
        self._loop = rpc.LoopServiceStub(self._channel)

    # -- plumbing ---------------------------------------------------------------------------

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        tok = f"token from {self.info.token_from}" if self.info.token else "no token"
        return f"Client({self.address!r}, {tok})"

    def _call(
        self,
        what: str,
        fn: Callable[..., T],
        request: Message,
        model_codes: tuple[str, ...] = (),
        timeout: float | None = 30.0,
    ) -> T:
        try:
            return fn(request, metadata=self._metadata, timeout=timeout)
        except grpc.RpcError as e:
            raise from_rpc(e, self.address, what, model_codes) from None

    # -- status -----------------------------------------------------------------------------

    def status(self) -> pb.Status:
        """The loop's and the server's status (the same as `hapticctl status`)."""
        return self._call("status", self._loop.GetStatus, pb.GetStatusRequest())

    def figures(self) -> dict[str, Any]:
        """The loop's figures as one flat dict: rate, steps, the ladder's rungs (on_time,
        late_one, held, fallback), latency percentiles (`round_trip_latency.p99_us`, ...), the
        active model's name; every scalar field of the status, nested ones joined by dots."""
        return _flatten(self.status())

    # -- models -----------------------------------------------------------------------------

    def models(self) -> list[pb.ModelInfo]:
        """Every model in the server's directory and every uploaded one, with its state."""
        return list(self._call("models", self._models.ListModels, pb.ListModelsRequest()).models)

    def active_model(self) -> pb.ModelInfo | None:
        """The model serving the loop, or None when it renders its fallback."""
        try:
            return self._models.GetActiveModel(
                pb.GetActiveModelRequest(), metadata=self._metadata, timeout=30.0
            )
        except grpc.RpcError as e:
            if e.code() == grpc.StatusCode.NOT_FOUND:
                return None
            raise from_rpc(e, self.address, "active model") from None

    def load(self, name: str) -> pb.ModelInfo:
        """Validate, warm and keep loaded a model of the server's directory (not active).
        BadModel says which check failed; the active model keeps serving."""
        r = self._call(
            f"load {name}", self._models.LoadModel, pb.LoadModelRequest(name=name),
            LOAD_MODEL_CODES, timeout=120.0,
        )  # fmt: skip
        return r.model

    def upload(self, path: str | Path, name: str | None = None) -> pb.ModelInfo:
        """Upload a local .onnx file and load it (as `name`, default the file's name). A file
        over the server's limit is refused here, before it is sent."""
        p = Path(path)
        try:
            data = p.read_bytes()
        except OSError as e:
            raise BadModel(f"upload: cannot read {p}: {e}") from None
        if not data:
            raise BadModel(f"upload: {p} is empty")
        limit = self.status().max_upload_bytes
        if limit and len(data) > limit:
            raise UploadRefused(
                f"upload: {p} is {len(data)} bytes, over the server's upload limit of {limit} "
                "bytes: put it in the server's model directory and load it by name",
                "RESOURCE_EXHAUSTED",
            )
        r = self._call(
            f"upload {p}", self._models.LoadModel,
            pb.LoadModelRequest(name=name or p.name, onnx=data), LOAD_MODEL_CODES, timeout=120.0,
        )  # fmt: skip
        return r.model

    def swap(self, model: str | Path) -> Swap:
        """Make a model the active one, loading it first if needed: a name in the server's
        directory, or a local file (a Path, or a str naming an existing .onnx file), uploaded
        first. Returns once the swap took effect, with the first step the new model answered."""
        local = Path(model)
        is_file = isinstance(model, Path) or ("/" in str(model) and local.is_file())
        name = self.upload(local).name if is_file else str(model)
        r = self._call(
            f"swap {name}", self._models.ActivateModel,
            pb.ActivateModelRequest(name=name, load_if_needed=True), ACTIVATE_MODEL_CODES,
            timeout=120.0,
        )  # fmt: skip
        return Swap(r.model, int(r.effective_step), tuple(r.warnings))

    def unload(self, name: str) -> None:
        """Drop a loaded model from the server's memory (not the active one)."""
        self._call(f"unload {name}", self._models.UnloadModel, pb.UnloadModelRequest(name=name))

    # -- experiments ------------------------------------------------------------------------

    def start_experiment(
        self,
        kind: str,
        *,
        ramp_rate: float | None = None,
        cycles: int | None = None,
        f_max_start: float | None = None,
        f_max_step: float | None = None,
    ) -> None:
        """Start an experiment on the loop, with the options of `hapticctl experiment start`
        (unset ones take the loop's defaults): ramp_rate N/s > 0, cycles 1..1000, f_max_start
        N > 0 (first peak force), f_max_step N >= 0 (added each cycle)."""
        req = pb.StartExperimentRequest(kind=kind)
        for k, v in (("ramp_rate", ramp_rate), ("cycles", cycles),
                     ("f_max_start", f_max_start), ("f_max_step", f_max_step)):  # fmt: skip
            if v is not None:
                setattr(req, k, v)
        self._call(f"start {kind}", self._loop.StartExperiment, req)

    def stop_experiment(self) -> None:
        """Stop the running experiment (the loop ramps down to 0 A safely)."""
        self._call("stop", self._loop.StopExperiment, pb.StopExperimentRequest())

    def wait_experiment(
        self, timeout: float | None = None, poll_s: float = 0.1, start_s: float = 2.0
    ) -> pb.Status:
        """Wait until the running experiment ends; returns the status then. A run just started
        may take a few steps to show up: it is looked for during `start_s` seconds first.
        TimeoutError after `timeout` seconds (None: no limit)."""
        t0 = time.monotonic()
        seen = False
        while True:
            s = self.status()
            running = s.experiment.running
            seen = seen or running
            if not running and (seen or time.monotonic() - t0 > start_s):
                return s
            if timeout is not None and time.monotonic() - t0 > timeout:
                raise TimeoutError(f"{s.experiment.kind} still running after {timeout} s")
            time.sleep(poll_s)

    def run_experiment(self, kind: str, timeout: float | None = None, **options: Any) -> pb.Status:
        """`start_experiment` then `wait_experiment`."""
        self.start_experiment(kind, **options)
        return self.wait_experiment(timeout)

    # -- telemetry --------------------------------------------------------------------------

    def telemetry_rows(
        self,
        decimation: int = PAGE_DECIMATION,
        *,
        seconds: float | None = None,
        count: int | None = None,
    ) -> Iterator[pb.TelemetrySample]:
        """Live telemetry, one `TelemetrySample` per bucket of `decimation` loop steps (min and
        max of every series over the bucket), until `count` samples or `seconds` of wall time
        (None: until the server ends the stream; break out of the loop to stop earlier)."""
        if decimation < 1:
            raise ValueError("decimation must be >= 1 loop step per sample")
        stream = self._loop.StreamTelemetry(
            pb.StreamTelemetryRequest(decimation=decimation), metadata=self._metadata,
            timeout=seconds,
        )  # fmt: skip
        n = 0
        try:
            for sample in stream:
                yield sample
                n += 1
                if count is not None and n >= count:
                    break
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.DEADLINE_EXCEEDED:  # the window's end
                raise from_rpc(e, self.address, "telemetry") from None
        finally:
            stream.cancel()

    def live_telemetry(self, decimation: int = PAGE_DECIMATION) -> LiveTelemetry:
        """One telemetry stream read by a background thread for as long as it is open: call
        `.drain()` whenever you like (e.g. to redraw a plot) for the buckets that arrived
        since the last call, as a `Telemetry`; `.close()` (or `with`) ends it. Nothing is lost
        between two drains, and a loop that idles (no experiment) does not block the caller."""
        if decimation < 1:
            raise ValueError("decimation must be >= 1 loop step per sample")
        stream = self._loop.StreamTelemetry(
            pb.StreamTelemetryRequest(decimation=decimation), metadata=self._metadata
        )
        return LiveTelemetry(stream, decimation, self.address)

    def telemetry(
        self, seconds: float = 5.0, decimation: int = PAGE_DECIMATION, *, count: int | None = None
    ) -> Telemetry:
        """`seconds` of live telemetry as columns (`.columns` NumPy arrays, `.to_polars()`,
        `.to_pandas()`); `steps_produced` is how far the loop's step counter moved meanwhile,
        so `steps_received / steps_produced` tells whether this client kept up."""
        before = self.status().step
        cols = to_columns(self.telemetry_rows(decimation, seconds=seconds, count=count))
        after = self.status().step
        return Telemetry(cols, decimation, steps_produced=int(after - before))


class LiveTelemetry:
    """A telemetry stream being read in the background (`Client.live_telemetry`)."""

    def __init__(self, stream: Any, decimation: int, address: str) -> None:
        self.decimation = decimation
        self._stream = stream
        self._address = address
        self._lock = threading.Lock()
        self._pending: list[pb.TelemetrySample] = []
        self._error: HapticsError | None = None
        self.received = 0  # samples received so far
        self._thread = threading.Thread(target=self._read, name="haptics-telemetry", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        try:
            for sample in self._stream:
                with self._lock:
                    self._pending.append(sample)
                    self.received += 1
        except grpc.RpcError as e:
            if e.code() != grpc.StatusCode.CANCELLED:  # cancelled: close() ended it
                self._error = from_rpc(e, self._address, "telemetry")

    def drain(self) -> Telemetry:
        """The buckets that arrived since the last drain (raises the stream's error, if any)."""
        with self._lock:
            got, self._pending = self._pending, []
        if self._error is not None and not got:
            raise self._error
        return Telemetry(to_columns(got), self.decimation)

    def close(self) -> None:
        self._stream.cancel()
        self._thread.join(5)

    def __enter__(self) -> LiveTelemetry:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _flatten(msg: Message, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in msg.DESCRIPTOR.fields:
        v = getattr(msg, f.name)
        key = prefix + f.name
        if f.message_type is not None and not is_repeated(f):
            out.update(_flatten(v, key + "."))
        elif f.enum_type is not None:
            out[key] = f.enum_type.values_by_number[v].name
        elif not is_repeated(f):
            out[key] = v
    return out


__all__ = ["Client", "LiveTelemetry", "Swap", "HapticsError", "EXPERIMENTS", "PAGE_DECIMATION"]

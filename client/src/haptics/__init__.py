"""The haptics system from Python (docs/python.md).

    import haptics
    client = haptics.Client()                 # finds the local system and its token
    client.status().rate_hz
    client.run_experiment("abstraction", cycles=3, ramp_rate=6.0)
    window = client.telemetry(seconds=5)      # NumPy columns; .to_polars(), .to_pandas()
    rec = haptics.read_recording("data/dataset/train_1.8.parquet")
"""

from .client import EXPERIMENTS, PAGE_DECIMATION, Client, LiveTelemetry, Swap
from .connection import ConnectionInfo, connection_file, resolve
from .errors import (
    BadModel,
    ConnectionFileError,
    HapticsError,
    NotPossibleNow,
    NotReachable,
    Refused,
    UploadRefused,
    WrongToken,
)
from .recording import RecordingFrame, read_recording
from .telemetry import Telemetry
from .v1 import haptics_pb2 as pb

__all__ = [
    "EXPERIMENTS",
    "PAGE_DECIMATION",
    "BadModel",
    "Client",
    "ConnectionFileError",
    "ConnectionInfo",
    "HapticsError",
    "LiveTelemetry",
    "NotPossibleNow",
    "NotReachable",
    "RecordingFrame",
    "Refused",
    "Swap",
    "Telemetry",
    "UploadRefused",
    "WrongToken",
    "connection_file",
    "pb",
    "read_recording",
    "resolve",
]

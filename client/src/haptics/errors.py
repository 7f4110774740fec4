"""Typed errors: each says what failed and what to do, in one sentence.

    HapticsError
    ├── NotReachable         no server answers at the address (or it went away)
    ├── ConnectionFileError  the connection file is unsafe or unreadable
    ├── WrongToken           the server wants a token for this call, or refused the one sent
    └── Refused              the server said no (`code` is the gRPC status name)
        ├── BadModel         a model that cannot be loaded: corrupt, wrong inputs, unknown
        │                    features, NaN on warm-up, no such file
        ├── UploadRefused    an upload over the server's limit
        └── NotPossibleNow   the state forbids it (no loop, an experiment already runs, ...)
"""

from __future__ import annotations

import grpc


class HapticsError(Exception):
    """Every error of this package."""


class NotReachable(HapticsError):
    """No infer-server answers at the address."""


class ConnectionFileError(HapticsError):
    """The connection file exists but cannot be trusted or read."""


class WrongToken(HapticsError):
    """UNAUTHENTICATED or PERMISSION_DENIED: no token, or not the server's."""


class Refused(HapticsError):
    """The server refused the call; `code` is the gRPC status code's name."""

    def __init__(self, message: str, code: str = "") -> None:
        super().__init__(message)
        self.code = code


class BadModel(Refused):
    """A model the server will not load (the message says which check failed)."""


class UploadRefused(Refused):
    """An upload over the server's size limit."""


class NotPossibleNow(Refused):
    """FAILED_PRECONDITION: not in the current state (no loop attached, a run already going)."""


#: The codes that are about the model in a load (FAILED_PRECONDITION: it needs features the loop
#: does not provide) and in an activation (there FAILED_PRECONDITION means no loop).
LOAD_MODEL_CODES = ("INVALID_ARGUMENT", "NOT_FOUND", "FAILED_PRECONDITION")
ACTIVATE_MODEL_CODES = ("INVALID_ARGUMENT", "NOT_FOUND")


def from_rpc(
    e: grpc.RpcError, address: str, call: str, model_codes: tuple[str, ...] = ()
) -> HapticsError:
    """The typed error for a failed call; `model_codes` name the status codes that mean a bad
    model for this call."""
    code: grpc.StatusCode = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
    details = (e.details() if hasattr(e, "details") else None) or str(e)
    name = code.name
    if code == grpc.StatusCode.UNAVAILABLE:
        return NotReachable(
            f"{call}: infer-server at {address} is not reachable ({details}). Is it running? "
            "(scripts/up.sh starts it; or pass address=... / set HAPTICS_ADDR)"
        )
    if code in (grpc.StatusCode.UNAUTHENTICATED, grpc.StatusCode.PERMISSION_DENIED):
        return WrongToken(
            f"{call}: {details}. This server requires its token (for every call): pass token=... "
            "or set HAPTICS_TOKEN (a local server's connection file provides it)"
        )
    if code in (grpc.StatusCode.RESOURCE_EXHAUSTED, grpc.StatusCode.OUT_OF_RANGE):
        return UploadRefused(f"{call}: upload refused: {details}", name)
    if name in model_codes:
        return BadModel(f"{call}: bad model: {details}", name)
    if code == grpc.StatusCode.FAILED_PRECONDITION:
        return NotPossibleNow(f"{call}: not possible now: {details}", name)
    return Refused(f"{call}: refused ({name}): {details}", name)

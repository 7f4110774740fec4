"""Where the running system is and which token it wants, found the way `hapticctl` finds them
(docs/python.md, "Finding the system").

infer-server writes a connection file once it listens (`<dir>/<instance>.json`, mode 0600, in a
directory of mode 0700: `$XDG_RUNTIME_DIR/haptics`, else `/tmp/haptics-<uid>`). The order:

- address: the explicit argument > `HAPTICS_ADDR` > the file's `grpc` > `http://127.0.0.1:50051`
- token: the explicit argument > `HAPTICS_TOKEN` > the file's `token`, only when the address in
  use is the file's address (a token is never sent to a server it was not written for) > none

A missing file (an older server, or none running) is not an error: the defaults apply."""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path

from .errors import ConnectionFileError

DEFAULT_ADDRESS = "http://127.0.0.1:50051"
DEFAULT_INSTANCE = "default"


def normalize_address(address: str) -> str:
    """"127.0.0.1:50051" and "http://127.0.0.1:50051" name the same server."""
    a = address.strip()
    return a if "://" in a else f"http://{a}"


def connection_dir() -> Path:
    """`$XDG_RUNTIME_DIR/haptics` when XDG_RUNTIME_DIR is set, non-empty and an existing
    directory; else `/tmp/haptics-<uid>`."""
    xdg = os.environ.get("XDG_RUNTIME_DIR", "")
    if xdg and Path(xdg).is_dir():
        return Path(xdg) / "haptics"
    return Path(f"/tmp/haptics-{os.getuid()}")


def connection_file(instance: str | None = None) -> Path:
    """`<dir>/<instance>.json`; the instance is the argument, else HAPTICS_INSTANCE, else
    `default`."""
    name = instance or os.environ.get("HAPTICS_INSTANCE") or DEFAULT_INSTANCE
    return connection_dir() / f"{name}.json"


def _check_private(path: Path, what: str) -> None:
    """A file that holds a token is trusted only when this user owns it and nobody else can
    read it (the same rule infer-server applies when it creates the directory)."""
    st = path.stat()
    if st.st_uid != os.getuid():
        raise ConnectionFileError(
            f"{what} {path} is owned by uid {st.st_uid}, not by you (uid {os.getuid()}): "
            "refusing to read a token from it"
        )
    if stat.S_IMODE(st.st_mode) & 0o077:
        raise ConnectionFileError(
            f"{what} {path} is accessible to group or others (mode "
            f"{stat.S_IMODE(st.st_mode):04o}): refusing to read a token from it (chmod go-rwx)"
        )


@dataclass(frozen=True)
class ConnectionInfo:
    """What a client connects to, and where each value came from (for error messages)."""

    address: str
    token: str | None
    address_from: str  # "argument" | "HAPTICS_ADDR" | "connection file <path>" | "default"
    token_from: str  # "argument" | "HAPTICS_TOKEN" | "connection file <path>" | "none"
    file: dict | None = None  # the connection file's contents, when one was read


def read_connection_file(instance: str | None = None) -> tuple[Path, dict] | None:
    """The instance's connection file, or None when there is none (an older server, or none
    running). A file that exists but is unsafe or unreadable raises ConnectionFileError."""
    path = connection_file(instance)
    if not path.exists():
        return None
    _check_private(path.parent, "connection directory")
    _check_private(path, "connection file")
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise ConnectionFileError(f"cannot read connection file {path}: {e}") from e
    if not isinstance(data, dict) or not isinstance(data.get("grpc"), str):
        raise ConnectionFileError(f"connection file {path} has no \"grpc\" address")
    return path, data


def resolve(
    address: str | None = None, token: str | None = None, instance: str | None = None
) -> ConnectionInfo:
    """Address and token by the order in the module's docstring. Empty strings count as unset
    (as in hapticctl)."""
    found = read_connection_file(instance)
    file_addr = normalize_address(found[1]["grpc"]) if found else None
    where = f"connection file {found[0]}" if found else ""

    env_addr = os.environ.get("HAPTICS_ADDR", "").strip()
    if address and address.strip():
        addr, addr_from = normalize_address(address), "argument"
    elif env_addr:
        addr, addr_from = normalize_address(env_addr), "HAPTICS_ADDR"
    elif file_addr:
        addr, addr_from = file_addr, where
    else:
        addr, addr_from = DEFAULT_ADDRESS, "default"

    env_token = os.environ.get("HAPTICS_TOKEN", "")
    file_token = found[1].get("token") if found else None
    if token:
        tok, tok_from = token, "argument"
    elif env_token:
        tok, tok_from = env_token, "HAPTICS_TOKEN"
    elif file_token and isinstance(file_token, str) and addr == file_addr:
        tok, tok_from = file_token, where
    else:
        tok, tok_from = None, "none"
    return ConnectionInfo(addr, tok, addr_from, tok_from, found[1] if found else None)

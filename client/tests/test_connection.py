"""How a client finds the system: the order of docs/python.md ("Finding the system"), with a
connection file written here as infer-server writes it, and without one (an older server)."""

import json
import os

import pytest

import haptics
from haptics import connection


@pytest.fixture
def rundir(tmp_path, monkeypatch):
    """XDG_RUNTIME_DIR in a temp folder, no HAPTICS_* variables."""
    for k in ("HAPTICS_ADDR", "HAPTICS_TOKEN", "HAPTICS_INSTANCE"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))
    return tmp_path


def write_file(rundir, instance="default", grpc="http://127.0.0.1:50999", token="feedc0de"):
    d = rundir / "haptics"
    d.mkdir(mode=0o700, exist_ok=True)
    os.chmod(d, 0o700)
    f = d / f"{instance}.json"
    f.write_text(json.dumps({
        "instance": instance, "pid": os.getpid(), "grpc": grpc, "http": "http://127.0.0.1:8099",
        "token": token, "page": f"http://127.0.0.1:8099/#token={token}",
    }))  # fmt: skip
    os.chmod(f, 0o600)
    return f


def test_without_a_connection_file_the_defaults_apply(rundir):
    info = connection.resolve()
    assert (info.address, info.token) == ("http://127.0.0.1:50051", None)
    assert (info.address_from, info.token_from) == ("default", "none")


def test_directory_is_xdg_runtime_dir_or_tmp(rundir, monkeypatch):
    assert connection.connection_file() == rundir / "haptics" / "default.json"
    monkeypatch.setenv("HAPTICS_INSTANCE", "bench2")
    assert connection.connection_file() == rundir / "haptics" / "bench2.json"
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(rundir / "does-not-exist"))
    assert connection.connection_dir() == connection.Path(f"/tmp/haptics-{os.getuid()}")
    monkeypatch.setenv("XDG_RUNTIME_DIR", "")
    assert connection.connection_dir() == connection.Path(f"/tmp/haptics-{os.getuid()}")


def test_the_file_gives_address_and_token(rundir):
    f = write_file(rundir)
    info = connection.resolve()
    assert (info.address, info.token) == ("http://127.0.0.1:50999", "feedc0de")
    assert info.address_from == info.token_from == f"connection file {f}"


def test_instance_picks_its_file(rundir, monkeypatch):
    write_file(rundir, "default", grpc="127.0.0.1:1")
    write_file(rundir, "other", grpc="127.0.0.1:2", token="aa")
    assert connection.resolve(instance="other").address == "http://127.0.0.1:2"
    monkeypatch.setenv("HAPTICS_INSTANCE", "other")
    assert connection.resolve().token == "aa"


def test_explicit_argument_beats_environment_beats_file(rundir, monkeypatch):
    write_file(rundir)
    monkeypatch.setenv("HAPTICS_ADDR", "127.0.0.1:7000")
    monkeypatch.setenv("HAPTICS_TOKEN", "envtok")
    info = connection.resolve()
    assert (info.address, info.token) == ("http://127.0.0.1:7000", "envtok")
    info = connection.resolve("http://127.0.0.1:7001", "argtok")
    assert (info.address, info.token, info.token_from) == (
        "http://127.0.0.1:7001", "argtok", "argument")  # fmt: skip


def test_the_files_token_goes_only_to_the_files_address(rundir, monkeypatch):
    write_file(rundir)
    # another address, by argument or HAPTICS_ADDR: the file's token is not sent there
    assert connection.resolve("127.0.0.1:7001").token is None
    monkeypatch.setenv("HAPTICS_ADDR", "127.0.0.1:7002")
    assert connection.resolve().token is None
    # the same address written either way: it is the file's server, the token goes
    assert connection.resolve("127.0.0.1:50999").token == "feedc0de"
    monkeypatch.setenv("HAPTICS_ADDR", "http://127.0.0.1:50999")
    assert connection.resolve().token == "feedc0de"


def test_a_null_token_in_the_file_means_none(rundir):
    write_file(rundir, token=None)
    info = connection.resolve()
    assert (info.address, info.token) == ("http://127.0.0.1:50999", None)


@pytest.mark.parametrize("target", ["dir", "file"])
def test_a_file_others_can_read_is_refused(rundir, target):
    f = write_file(rundir)
    os.chmod(f.parent if target == "dir" else f, 0o755 if target == "dir" else 0o644)
    with pytest.raises(haptics.ConnectionFileError, match="group or others"):
        connection.resolve()


def test_a_broken_file_is_a_clear_error(rundir):
    f = write_file(rundir)
    f.write_text("{not json")
    with pytest.raises(haptics.ConnectionFileError, match="cannot read connection file"):
        connection.resolve()


def test_nothing_listening_is_not_reachable(rundir):
    with pytest.raises(haptics.NotReachable, match="cannot reach infer-server at http://127.0.0.1:9"):
        haptics.Client("127.0.0.1:9", connect_timeout=0.5)

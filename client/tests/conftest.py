"""The real system for the client's tests: `rt-loop serve` on the simulated bench at 10 kHz and
`infer-server serve` attached to it, on free ports and an instance of their own (a developer's
running system is not touched), serving two spring models written here.

A missing binary FAILS under CI=true and is a counted skip elsewhere (pytest's "skipped")."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

import pytest

REPO = Path(__file__).resolve().parents[2]
#: The token the test server requires for changes (a server started by trust's code without
#: --token makes its own; the tests pass this one explicitly).
TOKEN = "c1a55e5" * 4


def missing(why: str) -> NoReturn:
    """A dependency of the test is missing: a failure under CI=true, a counted skip elsewhere."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"{why} (CI=true: a test that cannot run fails)", pytrace=False)
    pytest.skip(why)


def binary(name: str, env: str) -> Path:
    """$ENV, else target/release/NAME; a missing one is `missing()`."""
    if os.environ.get(env):
        p = Path(os.environ[env])
        if not p.is_file():
            pytest.fail(f"${env} is {p}, which is not a file", pytrace=False)
        return p
    p = REPO / "target" / "release" / name
    if not (p.is_file() and os.access(p, os.X_OK)):
        missing(f"{p} not built (cargo build --release -p {name})")
    return p


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def write_spring_models(out: Path) -> dict[str, Path]:
    """Two linear springs with damping over (position_x, velocity), built with the helpers of
    infer-server's own fixture script: a soft and a stiff one, so a swap shows in the force."""
    sys.path.insert(0, str(REPO / "infer-server" / "tests" / "fixtures"))
    try:
        import make_models as mm
    finally:
        sys.path.pop(0)
    out.mkdir(parents=True, exist_ok=True)
    files = {}
    for name, k in (("soft_spring", 250.0), ("stiff_spring", 600.0)):
        mm.finish(mm.linear_graph(2, [k, 5.0], 0.0), out, name, mm.meta("position_x,velocity"))
        files[name] = out / f"{name}.onnx"
    return files


@dataclass
class System:
    address: str
    http: str
    instance: str
    token: str
    models: dict[str, Path]
    loop: subprocess.Popen
    server: subprocess.Popen
    logs: Path

    def output(self) -> str:
        return "".join(
            f"--- {f.name}\n{f.read_text(errors='replace')[-3000:]}\n"
            for f in sorted(self.logs.glob("*.log"))
        )


def _stop(p: subprocess.Popen) -> None:
    if p.poll() is None:
        p.send_signal(2)  # SIGINT: a clean exit removes the segment and the connection file
        try:
            p.wait(10)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


@pytest.fixture(scope="session")
def system(tmp_path_factory: pytest.TempPathFactory) -> Iterator[System]:
    rt_loop = binary("rt-loop", "HAPTICS_RT_LOOP")
    server = binary("infer-server", "HAPTICS_INFER_SERVER")
    tmp = tmp_path_factory.mktemp("system")
    models = write_spring_models(tmp / "models")
    instance = f"pyclient-{os.getpid()}"
    grpc_port, http_port = free_port(), free_port()
    env = {k: v for k, v in os.environ.items() if not k.startswith("HAPTICS_")}
    loop_log = (tmp / "rt-loop.log").open("w")
    loop = subprocess.Popen(
        [str(rt_loop), "serve", "--clock", "realtime", "--rate-hz", "10000", "--board", "sim",
         "--instance", instance, "--wait", "spin-park"],
        cwd=REPO, env=env, stdout=loop_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    time.sleep(0.5)
    server_log = (tmp / "infer-server.log").open("w")
    srv = subprocess.Popen(
        [str(server), "serve", "--models", str(tmp / "models"), "--model", "soft_spring.onnx",
         "--instance", instance, "--grpc", f"127.0.0.1:{grpc_port}",
         "--http", f"127.0.0.1:{http_port}", "--wait", "spin-park", "--token", TOKEN,
         "--stats-every", "0"],
        cwd=REPO, env=env, stdout=server_log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    sys_ = System(f"http://127.0.0.1:{grpc_port}", f"http://127.0.0.1:{http_port}", instance,
                  TOKEN, models, loop, srv, tmp)  # fmt: skip
    try:
        import haptics

        deadline = time.monotonic() + 30
        while True:
            if srv.poll() is not None or loop.poll() is not None:
                pytest.fail(f"a process exited at start\n{sys_.output()}", pytrace=False)
            try:
                with haptics.Client(sys_.address, token=TOKEN, connect_timeout=1) as c:
                    if c.status().loop_alive:
                        break
            except haptics.NotReachable:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"the system did not come up in 30 s\n{sys_.output()}", pytrace=False)
            time.sleep(0.3)
        yield sys_
    finally:
        _stop(srv)
        _stop(loop)
        loop_log.close()
        server_log.close()


@pytest.fixture
def client(system: System) -> Iterator:
    import haptics

    with haptics.Client(system.address, token=system.token) as c:
        yield c

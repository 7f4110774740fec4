"""Builds the `haptics` package: its gRPC code is compiled from the repository's
proto/haptics/v1/haptics.proto by grpcio-tools at build and install time (also for an editable
install), into haptics/v1/ (git-ignored). The schema is written once, in the .proto."""

from __future__ import annotations

import hashlib
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

HERE = Path(__file__).resolve().parent
PROTO_ROOT = HERE.parent / "proto"
PROTO = PROTO_ROOT / "haptics" / "v1" / "haptics.proto"


def generate(out: Path) -> None:
    """haptics/v1/haptics_pb2.py, haptics_pb2.pyi and haptics_pb2_grpc.py under `out`, with a
    stamp (the .proto's sha256) so a stale copy can be told apart."""
    from grpc_tools import protoc  # a build requirement (pyproject.toml)

    if not PROTO.is_file():
        raise SystemExit(f"haptics client: {PROTO} not found (build from the repository)")
    pkg = out / "haptics" / "v1"
    pkg.mkdir(parents=True, exist_ok=True)
    args = [
        "grpc_tools.protoc",
        f"-I{PROTO_ROOT}",
        f"--python_out={out}",
        f"--pyi_out={out}",
        f"--grpc_python_out={out}",
        str(PROTO),
    ]
    if protoc.main(args) != 0:
        raise SystemExit(f"haptics client: grpc_tools.protoc failed on {PROTO}")
    (pkg / "__init__.py").write_text(
        '"""Generated from proto/haptics/v1/haptics.proto at install time (setup.py)."""\n'
        f'PROTO_SHA256 = "{hashlib.sha256(PROTO.read_bytes()).hexdigest()}"\n'
    )


class BuildWithProto(build_py):
    def run(self) -> None:
        # editable install: the package is imported from src/, so generate there
        generate(HERE / "src" if self.editable_mode else Path(self.build_lib))
        super().run()


setup(cmdclass={"build_py": BuildWithProto})

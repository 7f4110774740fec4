"""Shared fixtures: a small synthetic dataset (numpy fake sponge) and the project binaries."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from types import ModuleType
from typing import NoReturn

import pytest
import torch

from haptics_train.data import Dataset, load_dataset
from haptics_train.synthetic import write_dataset

REPO = Path(__file__).resolve().parents[2]

torch.set_num_threads(1)  # 2 threads on a busy 2-core box run ~10x slower


def missing(why: str) -> NoReturn:
    """A dependency of the test is missing: a failure under CI=true (a test that cannot run
    must not pass there), an explicit skip elsewhere (pytest counts it; scripts/test.sh prints
    the count)."""
    if os.environ.get("CI") == "true":
        pytest.fail(f"{why} (CI=true: a test that cannot run fails)", pytrace=False)
    pytest.skip(why)


def script_module(file: str) -> ModuleType:
    """A Python file of scripts/ (named with hyphens, so not importable by name) as a module."""
    path = REPO / "scripts" / file
    spec = importlib.util.spec_from_file_location(path.stem.replace("-", "_"), path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def binary(name: str, env: str) -> Path | None:
    """A built project binary: $ENV, else target/release, else target/debug.

    $ENV naming a file that does not exist is a mistake, never a reason to skip: it fails."""
    if os.environ.get(env):
        p = Path(os.environ[env])
        if not p.is_file():
            pytest.fail(f"${env} is {p}, which is not a file", pytrace=False)
        return p
    for sub in ("release", "debug"):
        p = REPO / "target" / sub / name
        if p.is_file() and os.access(p, os.X_OK):
            return p
    return None


@pytest.fixture(scope="session")
def synth_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_dataset(tmp_path_factory.mktemp("synth") / "dataset")


@pytest.fixture(scope="session")
def synth(synth_root: Path) -> Dataset:
    return load_dataset(synth_root)


@pytest.fixture(scope="session")
def fused_ops() -> Path:
    """The fused operators' library (fused-ops/: structured's and lawfree's default exports are
    one node of it); a missing one is a failure under CI=true, a counted skip elsewhere."""
    from haptics_train.ort_ops import PACKAGE, library_path

    p = library_path()
    if not p.is_file():
        missing(f"{p} does not exist (cargo build --release -p {PACKAGE})")
    return p


@pytest.fixture(scope="session")
def rt_loop() -> Path:
    p = binary("rt-loop", "HAPTICS_RT_LOOP")
    if p is None:
        missing("rt-loop binary not built (cargo build --release -p rt-loop)")
    return p


@pytest.fixture(scope="session")
def infer_server() -> Path:
    p = binary("infer-server", "HAPTICS_INFER_SERVER")
    if p is None:
        missing("infer-server binary not built (cargo build --release -p infer-server)")
    return p

"""Shared fixtures: the repository's scene files and the `ecp` command line (to check that the
package gives the same numbers and the same error messages)."""

import os
import pathlib
import subprocess

import pytest

import ecp

ROOT = pathlib.Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"


def scene_path(name: str) -> pathlib.Path:
    return SCENES / f"{name}.toml"


@pytest.fixture
def desk() -> ecp.Scene:
    return ecp.Scene.from_toml(scene_path("desk"))


@pytest.fixture
def a1() -> ecp.Scene:
    return ecp.Scene.from_toml(scene_path("a1_sliding"))


def ecp_binary() -> pathlib.Path:
    """The `ecp` binary: $ECP_BIN (scripts/test sets it), else the one `cargo test` builds."""
    path = pathlib.Path(os.environ.get("ECP_BIN", ROOT / "target" / "debug" / "ecp"))
    if not path.exists():
        pytest.skip(f"the ecp binary is not built ({path}); run scripts/test, which builds it")
    return path


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [str(ecp_binary()), *args], cwd=ROOT, capture_output=True, text=True, timeout=600
    )

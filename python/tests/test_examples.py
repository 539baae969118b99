"""The examples of python/examples run, with short settings, and say what they should."""

import pathlib
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "python" / "examples"


def run(name, *args):
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / name), *args], cwd=ROOT, capture_output=True, text=True, timeout=900
    )
    assert out.returncode == 0, out.stderr
    return out.stdout


def test_desk_example_writes_its_plot(tmp_path):
    png = tmp_path / "desk.png"
    text = run("desk.py", "--steps", "40", "--out", str(png))
    assert "40 steps" in text and "all converged: True" in text
    assert png.stat().st_size > 10_000
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_fit_example_recovers_mu_and_e_r():
    text = run("fit_friction.py", "--steps", "30")
    fitted = next(line for line in text.splitlines() if line.startswith("fitted:"))
    mu = float(fitted.split("mu = ")[1].split(",")[0])
    e_r = float(fitted.split("e_r = ")[1].split()[0])
    assert abs(mu - 0.22) < 0.005 and abs(e_r - 0.1) < 0.01, fitted


def test_ray_example_matches_the_local_batch():
    pytest.importorskip("ray")
    text = run("ray_sweep.py", "--mu", "3", "--fx", "2", "--steps", "10")
    assert "identical to ecp.batch: True" in text and "0 failed" in text

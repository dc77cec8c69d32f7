"""The package's layers (pyproject.toml, [tool.importlinter]) hold: no module imports
from a layer above its own, and the core imports no ROS."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINT = Path(sys.executable).with_name("lint-imports")


def lint(package_parent: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(package_parent)}
    return subprocess.run([str(LINT), "--config", str(ROOT / "pyproject.toml"), "--no-cache"], cwd=package_parent,
                          env=env, capture_output=True, text=True, timeout=300)


def test_every_layer_imports_only_from_below() -> None:
    run = lint(ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "2 kept, 0 broken" in run.stdout


def test_an_import_back_up_breaks_the_contract(tmp_path: Path) -> None:
    """The check is live: the models importing the CLI fail it, naming the import."""
    shutil.copytree(ROOT / "rheo_ros", tmp_path / "rheo_ros", ignore=shutil.ignore_patterns("__pycache__"))
    elements = tmp_path / "rheo_ros" / "models" / "elements.py"
    elements.write_text(elements.read_text() + "\nimport rheo_ros.app.cli  # noqa\n")
    run = lint(tmp_path)
    assert run.returncode != 0
    assert "rheo_ros.models.elements -> rheo_ros.app.cli" in run.stdout

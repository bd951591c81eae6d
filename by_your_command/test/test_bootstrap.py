"""The bootstrap is idempotent, and the wheel path fix-up rewrites exactly what it must.

How long a no-op bootstrap takes is measured in bench/bench_bootstrap.py, not asserted here.
"""

from __future__ import annotations

import importlib.util
import subprocess
from types import ModuleType

import pytest
from byc_testing import REPO_ROOT


def load_fixer() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "fix_ros_wheel_paths", REPO_ROOT / "scripts" / "fix_ros_wheel_paths.py"
    )
    assert spec and spec.loader
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.unit
def test_wheel_include_paths_are_rewritten() -> None:
    fixer = load_fixer()
    baked = (
        'INTERFACE_INCLUDE_DIRECTORIES "/opt/python/cp311-cp311/include/python3.11;'
        '/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"'
    )
    fixed = fixer.rewrite(baked, "/venv/include/python3.11", "/venv/numpy/include")
    assert fixed == 'INTERFACE_INCLUDE_DIRECTORIES "/venv/include/python3.11;/venv/numpy/include"'
    assert fixer.rewrite(fixed, "/x", "/y") == fixed


@pytest.mark.unit
def test_second_bootstrap_does_nothing() -> None:
    # make test has just bootstrapped this checkout, so nothing should be left to do.
    result = subprocess.run(
        ["bash", str(REPO_ROOT / "scripts" / "bootstrap.sh")], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().splitlines() == ["bootstrap: ready"], result.stdout

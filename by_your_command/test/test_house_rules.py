"""Rules that keep the package usable without ROS (agents must run where rclpy does not exist), and
imports between sub-packages running one way."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest
from byc_testing import INSTALL_LIB, REPO_ROOT

PACKAGE_DIR = REPO_ROOT / "by_your_command" / "by_your_command"
# Only these sub-packages may talk to ROS (DESIGN.md §2).
ROS_ALLOWED = {"nodes", "ros"}
ROS_ONLY_MODULES = (
    "rclpy",
    "rcl_interfaces",
    "builtin_interfaces",
    "std_msgs",
    "sensor_msgs",
    "geometry_msgs",
    "diagnostic_msgs",
    "by_your_command_msgs",
    "action_msgs",
    "rosidl_parser",
    "ament_index_python",
)
# Python source that makes every ROS package unimportable in the interpreter that runs it.
ROS_BLOCKER = (
    "import sys\n"
    f"_blocked = {ROS_ONLY_MODULES!r}\n"
    "class _BlockRos:\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] in _blocked:\n"
    "            raise ImportError(f'{name} is not available without ROS')\n"
    "sys.meta_path.insert(0, _BlockRos())\n"
)


def core_modules() -> list[Path]:
    return [
        path
        for path in sorted(PACKAGE_DIR.rglob("*.py"))
        if path.relative_to(PACKAGE_DIR).parts[0] not in ROS_ALLOWED
    ]


def ros_imports(path: Path, root: Path = REPO_ROOT) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        names: list[str] = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        found += [
            f"{path.relative_to(root)}:{node.lineno} imports {name}"
            for name in names
            if name.split(".")[0] in ROS_ONLY_MODULES
        ]
    return found


# Sub-packages that must not import others: the arrows run one way, prompts → commands →
# config_files (prompts expand the command vocabulary; both load their YAML with config_files).
ONE_WAY = {
    "commands": {"prompts"},
    "config_files": {"prompts", "commands"},
}


def sub_packages_imported(path: Path, package: str) -> list[tuple[int, str]]:
    """(line, sub-package of `package`) for each absolute import of one, `from package import x` too."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        modules: list[str] = []
        if isinstance(node, ast.Import):
            modules = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            modules = [f"{node.module}.{alias.name}" for alias in node.names]
        found += [
            (node.lineno, parts[1])
            for parts in (module.split(".") for module in modules)
            if parts[0] == package and len(parts) > 1
        ]
    return found


def backward_imports(package_dir: Path, root: Path = REPO_ROOT) -> list[str]:
    """Imports ONE_WAY forbids, in the package at `package_dir`."""
    return [
        f"{path.relative_to(root)}:{line} imports {package_dir.name}.{imported}"
        for importer, forbidden in ONE_WAY.items()
        for path in sorted((package_dir / importer).rglob("*.py"))
        for line, imported in sub_packages_imported(path, package_dir.name)
        if imported in forbidden
    ]


@pytest.mark.unit
def test_ros_is_imported_only_in_nodes() -> None:
    offences = [line for path in core_modules() for line in ros_imports(path)]
    assert not offences, "ROS imported outside nodes/ (agents must run without ROS):\n" + "\n".join(offences)


@pytest.mark.unit
def test_core_imports_with_ros_absent() -> None:
    """Import every core module in a Python where ROS packages cannot be imported at all."""
    modules = [
        ".".join(path.relative_to(PACKAGE_DIR.parent).with_suffix("").parts).removesuffix(".__init__")
        for path in core_modules()
    ]
    blocker = (
        ROS_BLOCKER + f"import importlib\nfor module in {modules!r}:\n    importlib.import_module(module)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(PACKAGE_DIR.parent)}
    result = subprocess.run([sys.executable, "-c", blocker], env=env, capture_output=True, text=True)
    assert result.returncode == 0, result.stderr


@pytest.mark.unit
def test_the_rule_checker_catches_an_offence(tmp_path: Path) -> None:
    offender = tmp_path / "leaky.py"
    offender.write_text("import os\nfrom rclpy.node import Node\nimport std_msgs.msg\nfrom . import rclpy\n")
    assert ros_imports(offender, tmp_path) == [
        "leaky.py:2 imports rclpy.node",
        "leaky.py:3 imports std_msgs.msg",
    ]


@pytest.mark.unit
def test_imports_between_sub_packages_run_one_way() -> None:
    offences = backward_imports(PACKAGE_DIR)
    assert not offences, f"imports against the one-way rule {ONE_WAY}:\n" + "\n".join(offences)


@pytest.mark.unit
def test_the_one_way_checker_catches_a_backward_import(tmp_path: Path) -> None:
    package = tmp_path / "by_your_command"
    for sub_package, source in {
        "commands": "from by_your_command.config_files import locate\nimport by_your_command.prompts.x\n",
        "config_files": "import os\nfrom by_your_command import commands\nfrom by_your_command import net\n",
        "prompts": "from by_your_command.commands import vocabulary\n",  # the allowed direction
    }.items():
        (package / sub_package).mkdir(parents=True)
        (package / sub_package / "module.py").write_text(source)
    assert backward_imports(package, tmp_path) == [
        "by_your_command/commands/module.py:2 imports by_your_command.prompts",
        "by_your_command/config_files/module.py:2 imports by_your_command.commands",
    ]


@pytest.mark.unit
def test_executables_are_installed_where_ros2_run_looks() -> None:
    byc = INSTALL_LIB / "byc"
    assert byc.is_file() and os.access(byc, os.X_OK), f"{byc} missing: run colcon build"
    result = subprocess.run([str(byc), "--version"], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0 and "by_your_command" in result.stdout


@pytest.mark.unit
def test_doctor_passes_in_the_project_environment() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "by_your_command.cli.byc", "doctor"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "ok    rclpy" in result.stdout

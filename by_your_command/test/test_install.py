"""`pip install` of by_your_command works on a machine without ROS, where agents run.

A wheel is built from the package and installed, with no network, into a fresh venv that has no
ROS: the project venv's site-packages lend it the dependencies, and every ROS import is blocked.
Used from another directory, it must find its config files and run its console scripts; its
metadata must declare what the code imports, within ranges the pinned lock (requirements/) meets.
"""

from __future__ import annotations

import ast
import email.parser
import json
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import venv
import zipfile
from importlib.metadata import packages_distributions
from pathlib import Path

import pytest
from byc_testing import REPO_ROOT
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from test_house_rules import ROS_BLOCKER, core_modules

PACKAGE_ROOT = REPO_ROOT / "by_your_command"
# What the wheel is built from: a copy, so build/ and *.egg-info never land in the checkout.
WHEEL_INPUTS = ("setup.py", "setup.cfg", "package.xml", "resource", "config", "by_your_command")
CONFIG_FILES = ("prompts.yaml", "commands.yaml", "bridge.yaml")
LOCK_FILES = ("ros.txt", "runtime.txt", "no-deps.txt")
PIP = [sys.executable, "-m", "pip", "--disable-pip-version-check"]

pytestmark = pytest.mark.unit


def run(args: list[str], env: dict[str, str] | None = None, cwd: Path | None = None) -> str:
    """stdout of a command that must succeed."""
    result = subprocess.run(args, capture_output=True, text=True, timeout=120, env=env, cwd=cwd)
    assert result.returncode == 0, f"{args}\n{result.stdout}\n{result.stderr}"
    return result.stdout


@pytest.fixture(scope="module")
def wheel(tmp_path_factory: pytest.TempPathFactory) -> Path:
    source = tmp_path_factory.mktemp("source")
    for name in WHEEL_INPUTS:
        origin = PACKAGE_ROOT / name
        if origin.is_dir():
            shutil.copytree(origin, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(origin, source / name)
    dist = tmp_path_factory.mktemp("dist")
    run(
        [*PIP, "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q", "-w", str(dist), str(source)]
    )
    (built,) = dist.glob("by_your_command-*.whl")
    return built


@pytest.fixture(scope="module")
def ros_free_venv(wheel: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A venv holding only the wheel; dependencies come from the project venv, ROS is blocked."""
    root = tmp_path_factory.mktemp("venv")
    venv.EnvBuilder(with_pip=False, symlinks=True).create(root)
    python = root / "bin" / "python"
    run([*PIP, "--python", str(python), "install", "--no-deps", "--no-index", "-q", str(wheel)])
    site = Path(run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"]).strip())
    # A path line: the project venv's own .pth hooks (the ROS wheels' among them) do not run.
    (site / "byc_project_deps.pth").write_text(sysconfig.get_path("purelib") + "\n")
    (site / "byc_block_ros.py").write_text(ROS_BLOCKER)
    (site / "byc_block_ros.pth").write_text("import byc_block_ros\n")
    return root


def ros_free_env(root: Path, home: Path) -> dict[str, str]:
    """No PYTHONPATH, no AMENT_PREFIX_PATH, no colcon install: what a machine without ROS has."""
    return {
        "PATH": f"{root / 'bin'}{os.pathsep}/usr/bin{os.pathsep}/bin",
        "HOME": str(home),
        "LANG": "C.UTF-8",
    }


def test_installed_wheel_finds_its_config_and_expands_prompts_without_ros(
    ros_free_venv: Path, tmp_path: Path
) -> None:
    probe = (
        "import json, by_your_command\n"
        "from by_your_command.config_files.locate import find_config_file\n"
        "from by_your_command.prompts.library import load_prompt_library\n"
        "try:\n    import rclpy\n    ros = True\nexcept ImportError:\n    ros = False\n"
        "library = load_prompt_library()\n"
        "default = library.selection.default\n"
        "print(json.dumps({'package': by_your_command.__file__, 'ros': ros, 'default': default,\n"
        f"    'files': [str(find_config_file(name)) for name in {CONFIG_FILES!r}],\n"
        "    'prompt': library.system_prompt(default), 'generated': sorted(library.generated_macros)}))\n"
    )
    env = ros_free_env(ros_free_venv, tmp_path)
    found = json.loads(run(["python", "-c", probe], env=env, cwd=tmp_path))
    package = Path(found["package"]).parent
    assert package.is_relative_to(ros_free_venv), found["package"]
    assert found["ros"] is False
    assert found["files"] == [str(package / "config" / name) for name in CONFIG_FILES]
    assert found["generated"], "the command macros from commands.yaml are missing"

    expanded = run(["expand_prompt", found["default"]], env=env, cwd=tmp_path)
    assert expanded == found["prompt"] + "\n"
    assert found["prompt"].strip()


def declared_requirements(wheel: Path) -> dict[str, list[Requirement]]:
    """Requires-Dist of the wheel by extra ("" = the core)."""
    with zipfile.ZipFile(wheel) as archive:
        (name,) = [entry for entry in archive.namelist() if entry.endswith(".dist-info/METADATA")]
        metadata = email.parser.Parser().parsestr(archive.read(name).decode())
    extras = metadata.get_all("Provides-Extra") or []
    declared: dict[str, list[Requirement]] = {extra: [] for extra in ["", *extras]}
    for line in metadata.get_all("Requires-Dist") or []:
        requirement = Requirement(line)
        if requirement.marker is None:
            declared[""].append(requirement)
        for extra in extras:
            if requirement.marker is not None and requirement.marker.evaluate({"extra": extra}):
                declared[extra].append(requirement)
    return declared


def third_party_imports(path: Path) -> tuple[set[str], set[str]]:
    """Top-level names of non-stdlib imports: (run when the module is imported, deferred)."""
    eager: set[str] = set()
    deferred: set[str] = set()

    def visit(node: ast.AST, is_deferred: bool) -> None:
        for child in ast.iter_child_nodes(node):
            child_deferred = is_deferred or isinstance(
                child, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda
            )
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                child_deferred = True
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [alias.name for alias in child.names]
            elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                names = [child.module]
            for top in {name.split(".")[0] for name in names}:
                if top not in sys.stdlib_module_names and top not in {"by_your_command", "__future__"}:
                    (deferred if child_deferred else eager).add(top)
            visit(child, child_deferred)

    visit(ast.parse(path.read_text(), filename=str(path)), False)
    return eager, deferred


def test_wheel_declares_what_the_core_imports(wheel: Path) -> None:
    declared = declared_requirements(wheel)
    core = {canonicalize_name(requirement.name) for requirement in declared[""]}
    everything = {canonicalize_name(req.name) for requirements in declared.values() for req in requirements}
    distributions = packages_distributions()
    missing: list[str] = []
    used: set[str] = set()
    for path in core_modules():
        eager, deferred = third_party_imports(path)
        for module, allowed, where in [(m, core, "the core") for m in eager] + [
            (m, everything, "the core or an extra") for m in deferred
        ]:
            names = {canonicalize_name(dist) for dist in distributions.get(module, [])}
            used |= names
            if not names & allowed:
                missing.append(f"{path.relative_to(REPO_ROOT)} imports {module}: not in {where}")
    assert not missing, "\n".join(missing)
    assert core <= used, f"declared but never imported: {sorted(core - used)}"
    assert {"aec", "audio"} <= declared.keys()


def pinned_versions() -> dict[str, str]:
    pins: dict[str, str] = {}
    for name in LOCK_FILES:
        for line in (REPO_ROOT / "requirements" / name).read_text().splitlines():
            match = re.fullmatch(r"([A-Za-z0-9._-]+)==(\S+)", line.split("#")[0].strip())
            if match:
                pins[canonicalize_name(match[1])] = match[2]
    return pins


def test_the_lock_meets_the_declared_ranges_and_the_readme_lists_them(wheel: Path) -> None:
    pins = pinned_versions()
    readme = (REPO_ROOT / "README.md").read_text()
    for requirements in declared_requirements(wheel).values():
        for requirement in requirements:
            pinned = pins.get(canonicalize_name(requirement.name))
            assert pinned, (
                f"{requirement.name} is declared but not pinned in requirements/ (CI never tests it)"
            )
            assert requirement.specifier.contains(pinned), (
                f"the lock's {requirement.name}=={pinned} is outside {requirement}"
            )
            assert f'"{requirement.name}{requirement.specifier}"' in readme, (
                f"README does not list {requirement}"
            )

"""Find a file shipped in the package's config directory, without ament_index (that needs ROS).

Search order: an explicit path; `<prefix>/share/by_your_command/config/<name>` for each prefix
in AMENT_PREFIX_PATH (a colcon install or a sourced ROS workspace); the `config/` directory next
to the Python package (a source checkout or `pip install -e`); last, the package's own `config/`
folder (package data of a wheel: `pip install` on a machine without ROS, where agents run).
Nothing found is an error that lists every place looked at: there is no built-in fallback.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE = "by_your_command"


class ConfigFileNotFound(FileNotFoundError):
    def __init__(self, name: str, searched: list[Path]) -> None:
        places = "\n  ".join(str(path) for path in searched) or "(nowhere: no search path)"
        super().__init__(f"cannot find {name}; looked in:\n  {places}")
        self.searched = searched


def candidate_paths(name: str, environ: dict[str, str] | None = None) -> list[Path]:
    env = os.environ if environ is None else environ
    prefixes = [entry for entry in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if entry]
    candidates = [Path(prefix) / "share" / PACKAGE / "config" / name for prefix in prefixes]
    package = Path(__file__).resolve().parents[1]
    candidates.append(package.parent / "config" / name)
    candidates.append(package / "config" / name)
    return candidates


def find_config_file(
    name: str, explicit: str | Path | None = None, environ: dict[str, str] | None = None
) -> Path:
    """The path of config file `name`, or of `explicit` when given (which must exist)."""
    if explicit:
        path = Path(explicit).expanduser()
        if not path.is_file():
            raise ConfigFileNotFound(str(path), [path])
        return path
    searched = candidate_paths(name, environ)
    for path in searched:
        if path.is_file():
            return path
    raise ConfigFileNotFound(name, searched)

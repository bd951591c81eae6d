"""Point the include paths baked into the ROS wheels at this venv.

The ros-jazzy-* wheels were built on a manylinux machine; their exported CMake
targets name that machine's Python and numpy include directories
(/opt/python/cpXY-cpXY/...). colcon cannot build an interface package until those
resolve, so rewrite them to this interpreter's directories. Idempotent.
"""

from __future__ import annotations

import re
import sys
import sysconfig
from pathlib import Path

import numpy

BUILD_MACHINE_PREFIX = re.compile(r"/opt/python/cp\d+-cp\d+")


def rewrite(text: str, python_include: str, numpy_include: str) -> str:
    numpy_pattern = BUILD_MACHINE_PREFIX.pattern + r"/lib/python[\d.]+/site-packages/numpy/_core/include"
    text = re.sub(numpy_pattern, numpy_include, text)
    return re.sub(BUILD_MACHINE_PREFIX.pattern + r"/include/python[\d.]+", python_include, text)


def main() -> int:
    python_include = sysconfig.get_paths()["include"]
    numpy_include = numpy.get_include()
    if not Path(python_include, "Python.h").is_file():
        print(
            f"fix_ros_wheel_paths: no Python.h in {python_include}; install the Python headers",
            file=sys.stderr,
        )
        return 1
    changed = 0
    for cmake_file in Path(sys.prefix, "share").glob("*/cmake/*Export.cmake"):
        text = cmake_file.read_text()
        if not BUILD_MACHINE_PREFIX.search(text):
            continue
        new_text = rewrite(text, python_include, numpy_include)
        if BUILD_MACHINE_PREFIX.search(new_text):
            print(f"fix_ros_wheel_paths: unknown build-machine path left in {cmake_file}", file=sys.stderr)
            return 1
        cmake_file.write_text(new_text)
        changed += 1
    print(f"fix_ros_wheel_paths: {changed} CMake export file(s) rewritten")
    return 0


if __name__ == "__main__":
    sys.exit(main())

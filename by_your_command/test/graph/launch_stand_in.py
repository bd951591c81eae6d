"""A stand-in for `ros2 launch`: `launch` and `launch_ros` are not on PyPI, so the launch tests
replace them with classes that record their arguments, and this module plays the launch service.
It follows the real one (launch 3.4.3, launch_ros 0.26.6, ros2launch) where our launch files
depend on it:

- arguments: every `name:=value` word becomes a launch configuration, declared or not (ros2launch
  includes the file with all of them), and stays in `context.argv`; `sys.argv` names the file;
- a process's exit runs its `on_exit` as launch does: actions (a `Shutdown` shuts down, return
  code unchanged), or a callable(event, context) whose exception LaunchService.run_async logs,
  then shuts everything down and returns 1;
- run as a process (`python launch_stand_in.py <profile> name:=value...`) it starts the graph's
  processes in its own process group, as launch does. Ctrl-C is what a terminal does, SIGINT to
  the whole group, children included; then launch sends its own SIGINT to each child (as a
  non-interactive launch does) LAUNCH_SIGINT_DELAY_S later; SIGTERM after the action's
  sigterm_timeout, SIGKILL SIGKILL_TIMEOUT_S later.
"""

from __future__ import annotations

import importlib.util
import os
import queue
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import FrameType, ModuleType, SimpleNamespace
from typing import Any

import yaml

from by_your_command.graph.processes import find_executable

LAUNCH_DIR = Path(__file__).resolve().parents[2] / "launch"
SELF = "launch"
# launch's event loop relays its SIGINT a few ms after the terminal's: a child that is still
# stopping then (a bigger graph's often are) takes it as a second Ctrl-C
LAUNCH_SIGINT_DELAY_S = 0.02
SIGKILL_TIMEOUT_S = 5.0  # launch's default sigkill_timeout


class Recorded:
    """A stand-in launch class: keeps its constructor arguments."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.args = args
        self.kwargs = kwargs


def kind(entity: object) -> str:
    return type(entity).__name__


def _module(name: str, **attributes: Any) -> ModuleType:
    module = ModuleType(name)
    for attribute, value in attributes.items():
        setattr(module, attribute, value)
    return module


def _recorded(name: str) -> type:
    return type(name, (Recorded,), {})


def stand_in_modules() -> dict[str, ModuleType]:
    """`launch`, `launch_ros` and the submodules our launch files use, as recording stand-ins."""
    action_names = (
        "DeclareLaunchArgument",
        "OpaqueFunction",
        "ExecuteProcess",
        "Shutdown",
        "RegisterEventHandler",
    )
    actions = _module("launch.actions", **{n: _recorded(n) for n in action_names})
    handlers = _module("launch.event_handlers", OnShutdown=_recorded("OnShutdown"))
    substitutions = _module("launch.substitutions", LaunchConfiguration=_recorded("LaunchConfiguration"))
    return {
        "launch": _module(
            "launch",
            LaunchDescription=_recorded("LaunchDescription"),
            actions=actions,
            event_handlers=handlers,
            substitutions=substitutions,
        ),
        "launch.actions": actions,
        "launch.event_handlers": handlers,
        "launch.substitutions": substitutions,
        "launch_ros": _module("launch_ros"),
        "launch_ros.actions": _module("launch_ros.actions", Node=_recorded("Node")),
        "launch_ros.substitutions": _module(
            "launch_ros.substitutions", ExecutableInPackage=_recorded("ExecutableInPackage")
        ),
    }


@dataclass
class Context:
    """What our launch code reads of launch.LaunchContext."""

    launch_configurations: dict[str, str]
    argv: list[str]
    locals: SimpleNamespace
    is_shutdown: bool = False
    noninteractive: bool = True


@dataclass
class StandInLaunch:
    """`ros2 launch by_your_command <profile>.launch.py <words>`, without processes."""

    profile: str
    words: list[str]
    command: list[str] = field(default_factory=list)  # sys.argv of `ros2`; default: naming this file
    return_code: int = 0
    errors: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.path = LAUNCH_DIR / f"{self.profile}.launch.py"
        if not self.command:
            self.command = ["ros2", "launch", "by_your_command", self.path.name, *self.words]
        self._on_shutdown: list[Any] = []
        self.context = Context({}, list(self.words), SimpleNamespace(current_launch_file_path=str(self.path)))

    def include(self) -> tuple[list[Recorded], list[Recorded]]:
        """(declared arguments, the graph's actions); an exception here makes `ros2 launch` exit 1."""
        spec = importlib.util.spec_from_file_location(f"launch_file_{self.profile}", self.path)
        assert spec and spec.loader, self.path
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        description = module.generate_launch_description()
        assert kind(description) == "LaunchDescription"
        entities = description.args[0]
        declared = [e for e in entities if kind(e) == "DeclareLaunchArgument"]
        (opaque,) = [e for e in entities if kind(e) == "OpaqueFunction"]
        for word in self.words:  # ros2launch: every argument is set, then defaults fill the rest
            name, _, value = word.partition(":=")
            self.context.launch_configurations[name] = value
        for argument in declared:
            self.context.launch_configurations.setdefault(argument.args[0], argument.kwargs["default_value"])
        saved_argv, sys.argv = sys.argv, self.command
        try:
            actions = opaque.kwargs["function"](self.context)
        finally:
            sys.argv = saved_argv
        for action in actions:
            if kind(action) == "RegisterEventHandler" and kind(action.args[0]) == "OnShutdown":
                self._on_shutdown.append(action.args[0].kwargs["on_shutdown"])
        return declared, actions

    def shutdown(self) -> None:
        if not self.context.is_shutdown:
            self.context.is_shutdown = True
            for handler in self._on_shutdown:
                handler(None, self.context)

    def process_exited(self, action: Recorded, returncode: int) -> None:
        on_exit = action.kwargs.get("on_exit")
        event = SimpleNamespace(returncode=returncode, action=action, process_name=action.kwargs["name"])
        try:
            entities = on_exit(event, self.context) if callable(on_exit) else on_exit
        except Exception as error:  # LaunchService.run_async: log it, shut down, return 1
            self.errors.append(str(error))
            self.return_code = 1
            self.shutdown()
            return
        if any(kind(entity) == "Shutdown" for entity in entities or []):
            self.shutdown()

    def sigterm_timeout(self, action: Recorded) -> float:
        timeout = action.kwargs.get("sigterm_timeout")
        if timeout is None:
            return 5.0  # launch's default
        name, default = timeout.args[0], timeout.kwargs["default"]
        return float(self.context.launch_configurations.get(name, default))


# -- run as a process ------------------------------------------------------------------------------


class _Child:
    def __init__(self, action: Recorded, argv: list[str]) -> None:
        self.action = action
        self.name: str = action.kwargs["name"]
        self.process = subprocess.Popen(  # no new session: launch's own process group
            argv,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self.reported = False

    def signal(self, signum: int) -> None:
        if self.process.poll() is None:
            print(
                f"[{SELF}] sending signal '{signal.Signals(signum).name}' to process[{self.name}]", flush=True
            )
            self.process.send_signal(signum)


def _argv(action: Recorded, run_dir: Path) -> list[str]:
    def executable(name: str) -> str:
        found = find_executable(name)
        assert found, f"executable {name} not found"
        return found

    if kind(action) == "ExecuteProcess":
        first, *rest = action.kwargs["cmd"]
        return [executable(first.kwargs["executable"]), *rest]
    name = action.kwargs["name"]
    params = run_dir / f"{name}.yaml"  # launch_ros writes dict parameters keyed `/**` too
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": action.kwargs["parameters"][0]}}))
    argv = [executable(action.kwargs["executable"]), "--ros-args", "-r", f"__node:={name}"]
    argv += ["-r", f"__ns:={action.kwargs['namespace']}", "--params-file", str(params)]
    for source, target in action.kwargs["remappings"]:
        argv += ["-r", f"{source}:={target}"]
    return argv


class _Runner:
    def __init__(self, launch: StandInLaunch, actions: list[Recorded], run_dir: Path) -> None:
        self.launch = launch
        self.lines: queue.Queue[tuple[str, str]] = queue.Queue()
        self.ctrl_c = False
        signal.signal(signal.SIGINT, self.on_sigint)
        self.sigint_at: float | None = None  # when launch relays its own SIGINT
        self.sigterm_at: float | None = None
        self.sigkill_at: float | None = None
        processes = [a for a in actions if kind(a) in ("Node", "ExecuteProcess")]
        self.children = [_Child(action, _argv(action, run_dir)) for action in processes]
        for child in self.children:
            print(f"[{SELF}] started {child.name} (pid {child.process.pid})", flush=True)
            threading.Thread(target=self._read, args=(child,), daemon=True).start()

    def _read(self, child: _Child) -> None:
        assert child.process.stdout is not None
        for line in child.process.stdout:
            self.lines.put((child.name, line.rstrip("\n")))

    def on_sigint(self, _signum: int, _frame: FrameType | None) -> None:
        self.ctrl_c = True

    def _begin_stop(self, relay_sigint_in: float) -> None:
        now = time.monotonic()
        self.launch.shutdown()
        self.sigint_at = now + relay_sigint_in
        self.sigterm_at = now + max(self.launch.sigterm_timeout(c.action) for c in self.children)
        self.sigkill_at = self.sigterm_at + SIGKILL_TIMEOUT_S

    def _until_next_deadline(self) -> float:
        deadlines = [d for d in (self.sigint_at, self.sigterm_at, self.sigkill_at) if d is not None]
        return min([0.05, *(max(d - time.monotonic(), 0.001) for d in deadlines)])

    def _escalate(self) -> None:
        now = time.monotonic()
        if self.sigint_at is not None and now >= self.sigint_at:
            self.sigint_at = None
            self._signal_all(signal.SIGINT)
        if self.sigterm_at is not None and now >= self.sigterm_at:
            self.sigterm_at = None
            self._signal_all(signal.SIGTERM)
        if self.sigkill_at is not None and now >= self.sigkill_at:
            self.sigkill_at = None
            self._signal_all(signal.SIGKILL)

    def _signal_all(self, signum: int) -> None:
        for child in self.children:
            child.signal(signum)

    def run(self) -> int:
        while not all(child.reported for child in self.children):
            try:
                name, line = self.lines.get(timeout=self._until_next_deadline())
                print(f"[{name}] {line}", flush=True)
            except queue.Empty:
                pass
            if self.ctrl_c and not self.launch.context.is_shutdown:
                print(f"[{SELF}] user interrupted with ctrl-c (SIGINT)", flush=True)
                self._begin_stop(LAUNCH_SIGINT_DELAY_S)
            for child in self.children:
                status = child.process.poll()
                if status is None or child.reported:
                    continue
                child.reported = True
                print(f"[{SELF}] process[{child.name}] exited with status {status}", flush=True)
                stopping = self.launch.context.is_shutdown
                self.launch.process_exited(child.action, status)
                if self.launch.context.is_shutdown and not stopping:
                    self._begin_stop(0.0)  # a shutdown not due to Ctrl-C: launch sends SIGINT at once
            self._escalate()
        while not self.lines.empty():
            name, line = self.lines.get()
            print(f"[{name}] {line}", flush=True)
        for error in self.launch.errors:
            print(f"[{SELF}] Caught exception in launch: {error}", flush=True)
        return self.launch.return_code


def main(argv: list[str]) -> int:
    profile, *words = argv
    sys.modules.update(stand_in_modules())
    launch = StandInLaunch(profile, words)
    try:
        _, actions = launch.include()
    except Exception as error:
        print(f"[{SELF}] Caught exception in launch: {error}", flush=True)
        return 1
    with tempfile.TemporaryDirectory(prefix="byc-stand-in-launch-") as run_dir:
        status = _Runner(launch, actions, Path(run_dir)).run()
    launch.shutdown()  # removes the agents' run dir, as OnShutdown does
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

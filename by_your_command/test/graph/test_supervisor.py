"""The supervisor behind `byc up`, with plain Python children (no ROS): quick, and covers what real
nodes rarely do (ignore SIGTERM, exit with status 0, print half a line)."""

from __future__ import annotations

import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager

import pytest
from byc_testing import running_process, wait_for
from graph.up_runner import UpProcess, pid_alive, wait_for_exit


def python(code: str) -> tuple[str, ...]:
    return (sys.executable, "-c", code)


# A child that says it is ready, then waits for a signal (no timer: it lives until it is stopped).
READY = "import signal; print('ready', flush=True)\nwhile True: signal.pause()"
STUBBORN = python(f"import signal; signal.signal(signal.SIGTERM, signal.SIG_IGN)\n{READY}")
POLITE = python(READY)
QUITTER = python("import sys; sys.stdout.write('bye without newline'); sys.stdout.flush()")


def supervise(children: dict[str, tuple[str, ...]], stop_timeout_s: float = 30.0) -> list[str]:
    """A supervisor process running `children` (name -> argv)."""
    specs = ", ".join(f"ProcessSpec({name!r}, {argv!r})" for name, argv in children.items())
    script = (
        "import sys\n"
        "from by_your_command.graph.processes import ProcessSpec\n"
        "from by_your_command.graph.supervisor import Supervisor, SupervisorConfig\n"
        f"config = SupervisorConfig(stop_timeout_s={stop_timeout_s})\n"
        f"sys.exit(Supervisor([{specs}], sys.stdout, config=config).run())\n"
    )
    return [sys.executable, "-c", script]


@contextmanager
def supervisor(children: dict[str, tuple[str, ...]], stop_timeout_s: float = 30.0) -> Iterator[UpProcess]:
    with running_process(supervise(children, stop_timeout_s)) as process:
        yield UpProcess(process)


def ready(up: UpProcess, *names: str) -> None:
    wait_for(
        lambda: (
            all(any(line.endswith("] ready") for line in up.lines_of(n)) for n in names) or up.check_running()
        ),
        what=f"{names} to print ready",
    )


@pytest.mark.unit
def test_a_child_ignoring_sigterm_is_killed_after_the_deadline() -> None:
    with supervisor({"stubborn": STUBBORN, "polite": POLITE}, stop_timeout_s=0.5) as up:
        ready(up, "stubborn", "polite")
        children = up.children()
        status = up.stop(signal.SIGTERM)
    assert status == 1, up.output
    assert "stubborn: still running 0.5 s after SIGTERM: SIGKILL" in up.output
    assert f"stubborn stopped uncleanly (exit status {-signal.SIGKILL})" in up.output
    assert "polite stopped" in up.output  # died of our SIGTERM: a clean stop
    assert not any(map(pid_alive, children.values()))


@pytest.mark.unit
def test_a_child_ending_on_its_own_is_a_failure_even_with_status_0() -> None:
    with supervisor({"quitter": QUITTER, "polite": POLITE}) as up:
        status = wait_for_exit(up)
    assert status == 1, up.output
    assert "[quitter] bye without newline" in up.output  # a last partial line is not lost
    assert "quitter exited with status 0: stopping the others" in up.output
    assert "FAILED: quitter (exit status 0)" in up.lines[-1]


@pytest.mark.unit
def test_a_missing_program_stops_what_already_started() -> None:
    with supervisor({"polite": POLITE, "ghost": ("/nonexistent/ghost",)}) as up:
        status = wait_for_exit(up)
    assert status == 1, up.output
    assert "cannot start ghost" in up.output and "polite stopped" in up.output


@pytest.mark.unit
def test_children_do_not_get_the_terminal_ctrl_c_directly() -> None:
    """Ctrl-C goes to the whole foreground process group; children run in their own sessions, so
    only the supervisor gets it and stops them in order (a second signal would kill a node at once)."""
    with supervisor({"polite": POLITE}) as up:
        ready(up, "polite")
        pid = up.children()["polite"]
        assert subprocess.run(
            ["ps", "-o", "sid=", "-p", str(pid)], capture_output=True, text=True
        ).stdout.strip() == str(pid)
        assert up.stop(signal.SIGINT) == 0, up.output

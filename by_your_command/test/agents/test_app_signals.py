"""An agent process's stop signals: one Ctrl-C delivered twice (by the terminal to the process
group, and by `ros2 launch` to each child) is one orderly stop; a later second signal exits at once.
Each case runs in a child process: the emergency exit would end the test runner itself."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap

import pytest
from byc_testing import wait_for

pytestmark = [pytest.mark.unit, pytest.mark.timeout(60)]

AGENT_STOPPING = textwrap.dedent(
    """
    import asyncio, sys
    from by_your_command.agents.app import _stop_on_signals

    async def main() -> None:
        stopped = asyncio.Event()
        with _stop_on_signals(stopped.set):
            print("ready", flush=True)
            await stopped.wait()
            print("stopping in order", flush=True)
            await asyncio.sleep(float(sys.argv[1]))  # the session's close, the last metrics
            print("stopped in order", flush=True)

    asyncio.run(main())
    """
)


def agent_like(closing_s: float) -> subprocess.Popen[str]:
    process = subprocess.Popen(
        [sys.executable, "-c", AGENT_STOPPING, str(closing_s)], stdout=subprocess.PIPE, text=True
    )
    assert process.stdout is not None
    assert process.stdout.readline().strip() == "ready"
    return process


def test_one_ctrl_c_sent_twice_is_one_orderly_stop() -> None:
    process = agent_like(closing_s=0.5)
    assert process.stdout is not None
    os.kill(process.pid, signal.SIGINT)  # the terminal's, to the whole process group
    assert process.stdout.readline().strip() == "stopping in order"
    os.kill(process.pid, signal.SIGINT)  # launch's own copy, a moment later
    out, _ = process.communicate(timeout=30)
    assert process.returncode == 0 and out.strip() == "stopped in order"


def test_a_later_signal_still_exits_at_once() -> None:
    process = agent_like(closing_s=60.0)
    assert process.stdout is not None
    os.kill(process.pid, signal.SIGINT)
    assert process.stdout.readline().strip() == "stopping in order"
    os.kill(process.pid, signal.SIGTERM)  # launch's escalation, or a person who insists
    wait_for(lambda: process.poll() is not None, timeout=30, what="the emergency exit")
    assert process.returncode == 128 + signal.SIGTERM

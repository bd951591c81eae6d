"""Start, spin and stop a node the same way everywhere (ros2 run, byc, tests)."""

from __future__ import annotations

import faulthandler
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from types import FrameType
from typing import Any

import rclpy
from rclpy.duration import Duration
from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.logging import get_logger
from rclpy.node import Node
from rclpy.qos import QoSReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from by_your_command.stop_signals import StopRequests, StopVerdict

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
SPIN_STOP_TIMEOUT_S = 5.0  # a callback still running after this is abandoned (logged)
# A process-directed signal goes to another thread when the main one already has one pending; the
# handler then runs only once the main thread wakes, so its wait wakes this often to let it.
SIGNAL_CHECK_S = 1.0
ACK_TIMEOUT_S = 2.0  # total wait for subscribers to acknowledge the last reliable messages
# Every step of a stop is bounded (about 9 s in practice); rclpy's and DDS's teardown and the
# interpreter's exit are not (a bridge once hung there past 30 s in CI, cause unknown: nothing was
# printed). A stop still running after this is stuck: every thread's
# stack goes to stderr and the process exits with EXIT_FAILED. Below launch's sigterm_timeout (20 s
# here), whose SIGTERM would end the process without saying where it was stuck.
STOP_DEADLINE_S = 18.0
EXIT_FAILED = 1

_log = get_logger("run_node")


def _say(text: str) -> None:
    """Written from a signal handler: plain stderr, not the rcl logger."""
    sys.stderr.write(f"run_node: {text}\n")
    sys.stderr.flush()


class _StopRequest:
    """Why and when the main thread should stop waiting: a signal or a dead executor thread."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.requests = StopRequests()
        self.failure: BaseException | None = None

    def on_signal(self, signum: int, _frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        verdict = self.requests.receive(signum)
        if verdict is StopVerdict.EXIT_NOW:
            # The graceful path is stuck (a hook, a callback, DDS): the user insists.
            _say(f"second {name}: exiting now; where the stop was:")
            faulthandler.dump_traceback(file=sys.stderr, all_threads=True)
            os._exit(128 + signum)
        if verdict is StopVerdict.SAME_STOP:
            _say(f"{name} again right away (the same Ctrl-C, sent twice): still stopping in order")
            return
        _say(f"{name}: stopping")
        self.event.set()

    def on_failure(self, error: BaseException) -> None:
        self.failure = error
        self.event.set()


def _arm_stop_deadline() -> None:
    """Once stopping, the process ends by STOP_DEADLINE_S (armed until it exits: the interpreter's
    own exit joins threads too). Only in the main thread: a test running run_node in a thread keeps
    its process."""
    if threading.current_thread() is threading.main_thread():
        faulthandler.dump_traceback_later(STOP_DEADLINE_S, exit=True, file=sys.stderr)


class _StopFuture(Future):
    """The future the executor spins until, keeping one wake-up callback instead of millions.

    rclpy's executors (Jazzy's rclpy 7.1.6 included; upstream fix: ros2/rclpy#1374) add a new
    `lambda x: self.wake()` to this future on every spin_once_until_future_complete, i.e. once per
    callback run, and hold them all until it completes: ~250 bytes per message, 110 MB an hour for
    an audio node at 4x real time (found by bench/soak.py; bench/bench_memory.py measures it). One
    wake-up is all it needs: they are all the same executor's wake(). Once done, a late addition is
    passed on (rclpy then calls it at once), so nothing waits for a wake-up that already happened.
    """

    def __init__(self) -> None:
        super().__init__()
        self._has_wake_up = False

    def add_done_callback(self, callback: Callable[[Future], None]) -> None:
        if self._has_wake_up and not self.done():
            return
        self._has_wake_up = True
        super().add_done_callback(callback)


class _Spinner:
    """Spins the executor in a thread until told to stop; reports an escaping exception."""

    def __init__(self, executor: Executor, stop: _StopRequest) -> None:
        self._executor = executor
        self._stop = stop
        self._done: Future = _StopFuture()
        self._thread = threading.Thread(target=self._run, name="executor", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def _run(self) -> None:
        try:
            self._executor.spin_until_future_complete(self._done)
        except ExternalShutdownException:
            self._stop.event.set()  # the context was shut down from elsewhere: stop quietly
        except BaseException as error:  # a callback raised: the node must not spin on half-dead
            _log.error(f"executor thread died: {type(error).__name__}: {error}")
            self._stop.on_failure(error)
        else:
            self._stop.event.set()  # spin returned by itself (context no longer ok)

    def stop(self) -> bool:
        """Ask the spin loop to return and wait for it; False when a callback did not finish in time."""
        self._done.set_result(None)  # wakes the executor's wait
        self._thread.join(SPIN_STOP_TIMEOUT_S)
        return not self._thread.is_alive()


def _install_handlers(stop: _StopRequest) -> dict[int, Any]:
    previous: dict[int, Any] = {}
    if threading.current_thread() is not threading.main_thread():
        return previous  # only the main thread may set handlers (a test calling run_node in a thread)
    for signum in STOP_SIGNALS:
        previous[signum] = signal.signal(signum, stop.on_signal)
    return previous


def _restore_handlers(previous: dict[int, Any]) -> None:
    for signum, handler in previous.items():
        signal.signal(signum, handler)


def _call_before_shutdown(node: Node) -> bool:
    hook = getattr(node, "before_shutdown", None)
    if hook is None:
        return True
    try:
        hook()
    except Exception as error:  # still shut down; the exit code says it was not clean
        _log.error(f"{node.get_name()}.before_shutdown failed: {type(error).__name__}: {error}")
        return False
    return True


def _wait_for_acks(node: Node, budget_s: float) -> None:
    """Let reliable subscribers receive what was just published before the participant goes away."""
    deadline = time.monotonic() + budget_s
    for publisher in list(node.publishers):
        if publisher.qos_profile.reliability != QoSReliabilityPolicy.RELIABLE:
            continue
        left = max(deadline - time.monotonic(), 0.0)
        try:
            acked = publisher.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9)))
        except Exception as error:  # a publisher already gone: nothing left to wait for
            _log.warning(f"cannot wait for acks on {publisher.topic_name}: {error}")
            continue
        if not acked:
            _log.warning(f"not every subscriber of {publisher.topic_name} acknowledged within {budget_s} s")


def run_node(make_node: Callable[[], Node], args: Sequence[str] | None = None, threads: int = 1) -> None:
    """Create the node, spin until SIGINT/SIGTERM, then stop it cleanly; raise SystemExit(1) on failure.

    rclpy's own signal handlers are off: they shut the context down at once, so nothing the node
    publishes while stopping (an utterance's end marker, "not speaking") would reach anyone. Instead
    the executor spins in a thread and the main thread waits on an event, which a signal interrupts
    at once (lock waits are interruptible on POSIX). On SIGINT/SIGTERM, in order:

    1. the executor stops (a callback in flight finishes, bounded by SPIN_STOP_TIMEOUT_S; with
       threads > 1, callbacks already handed to the pool may still be running);
    2. `node.before_shutdown()` runs if the node defines it, with the context still alive and no
       callback running concurrently: the place to publish final state;
    3. reliable publishers wait (at most ACK_TIMEOUT_S in total) until subscribers acknowledged;
    4. the node is destroyed (`destroy_node` may still publish and close devices), rclpy shut down.

    A second signal exits at once (status 128 + signal), except a SIGINT repeated right away: that
    is one Ctrl-C sent twice (terminal and launcher; by_your_command.stop_signals), and says where
    the stop was (every thread's stack). A stop that outlasts STOP_DEADLINE_S does the same by
    itself and exits with 1. An exception escaping a callback is logged and stops the node the same
    way, then the process exits with 1.
    """
    rclpy.init(args=list(args) if args is not None else None, signal_handler_options=SignalHandlerOptions.NO)
    stop = _StopRequest()
    previous = _install_handlers(stop)
    node: Node | None = None
    executor: Executor | None = None
    clean = True
    try:
        node = make_node()
        executor = SingleThreadedExecutor() if threads <= 1 else MultiThreadedExecutor(num_threads=threads)
        executor.add_node(node)
        spinner = _Spinner(executor, stop)
        spinner.start()
        while not stop.event.wait(SIGNAL_CHECK_S):
            pass  # the timeout lets the main thread run a handler whose signal another thread took
        _arm_stop_deadline()
        if not spinner.stop():
            _log.error(f"a callback still runs after {SPIN_STOP_TIMEOUT_S} s: stopping without it")
            clean = False
        clean = _call_before_shutdown(node) and clean and stop.failure is None
        _wait_for_acks(node, ACK_TIMEOUT_S)
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        if not stop.requests.stopping:
            _restore_handlers(previous)
        # else ours stay: a copy of the Ctrl-C may still come (launch relays it), and the default
        # handler would turn it into a KeyboardInterrupt while the process exits
    if not clean:
        raise SystemExit(EXIT_FAILED)

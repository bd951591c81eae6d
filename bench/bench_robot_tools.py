"""What the agent adds to a robot tool (issue 35; goal: <= 20 ms added at p95): the model's tool call
→ the goal at the robot's action server, against a raw rclpy ActionClient sending the same goal to
the same server in the same run; and the way back: the server's feedback → the model
(Provider.send_tool_progress), the server's result → the model (Provider.send_tool_results).

Ours: ros_ai_bridge as a process (a tools file naming the action `navigate_to_pose`, relative, in a
namespace of its own) and, in this process, an AgentRuntime (role tools; asyncio loop on a thread)
over a real BridgePort and BridgeClient, with a scripted provider: a typed turn ("go to the
kitchen", published on prompt_text) makes it emit a ToolCall and ResponseDone; it stamps that
emission and every send_tool_progress / send_tool_results.

The robot: an rclpy ActionServer (by_your_command_msgs/action/NavigateToPose) in this process, its
own DDS participant, on a MultiThreadedExecutor: it stamps each goal in its goal callback, then
publishes FEEDBACKS feedback messages (stamping each publish, and waiting until the consumer got it
so none is coalesced) and succeeds (stamped just before succeed()).
Baseline: a raw ActionClient on a second participant of this process; send_goal_async is called on
its executor's thread (rclpy's ActionClient is not thread-safe, the bridge does the same), stamped
just before the call; its feedback and result callbacks are stamped. Baseline and ours alternate,
one goal at a time, so machine noise hits both. `added` = ours − baseline, percentile by percentile.

The tools file asks for every feedback (feedback.every_s): tools/config.py refuses 0 (it must be
> 0), so it is 0.000001 s, the same as 0 at the pace of these goals.

    scripts/run.sh python bench/bench_robot_tools.py [--trials N] [--feedbacks K]
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import os
import sys
import tempfile
import threading
import time
from collections.abc import AsyncIterator, Callable, Sequence
from concurrent.futures import Future
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _agent_bench import Process, node_command, percentile, summary, wait_until  # noqa: E402

from by_your_command.agents import model_tool_calls  # noqa: E402
from by_your_command.agents.bridge_port import BridgePort  # noqa: E402
from by_your_command.agents.config import AgentConfig, parse_agent_config  # noqa: E402
from by_your_command.agents.events import ProviderEvent, ResponseDone, ResponseStatus, ToolCall  # noqa: E402
from by_your_command.agents.provider import SessionSetup, ToolResult  # noqa: E402
from by_your_command.agents.runtime import AgentRuntime  # noqa: E402
from by_your_command.bridge.client import BridgeClient  # noqa: E402

BENCH = "robot_tools"
GOAL_ADDED_P95_MS = 20.0
WARMUP = 3  # goals of each kind not counted (discovery, first conversions, session open)
WAIT_S = 15.0  # one goal's round trip, generously
ACK_WAIT_S = 5.0  # the server waits this long for a feedback to reach its consumer
ACTION = "navigate_to_pose"
ACTION_TYPE = "by_your_command_msgs/action/NavigateToPose"
OURS_X, BASELINE_X = 2.0, 3.0  # the goal's x tells whose goal the server got
TOOLS = f"""
tools:
  go_to:
    description: Drive to the kitchen and stop there.
    action: {ACTION}
    type: {ACTION_TYPE}
    fixed: {{pose.header.frame_id: map}}
    arguments:
      place:
        description: where to go
        choices:
          kitchen: {{pose.pose.position.x: {OURS_X}, pose.pose.orientation.w: 1.0}}
    feedback: {{every_s: 0.000001, fields: [distance_remaining]}}
    timeout_s: 10
"""
GO_TO = json.dumps({"place": "kitchen"})


# --- the robot: an action server, and the raw client of the baseline ----------------------------


@dataclass
class ServerStamps:
    goals: list[tuple[float, float]] = field(default_factory=list)  # (goal's x, when it arrived)
    feedback: list[float] = field(default_factory=list)  # each publish_feedback
    results: list[float] = field(default_factory=list)  # just before succeed()
    unacknowledged: int = 0  # feedback its consumer did not get within ACK_WAIT_S


class Robot:
    """The action server (its own participant) and the bench's prompt_text publisher."""

    def __init__(self, namespace: str, feedbacks: int) -> None:
        import rclpy
        from by_your_command_msgs.action import NavigateToPose
        from rclpy.action import ActionServer, GoalResponse
        from rclpy.callback_groups import ReentrantCallbackGroup
        from rclpy.executors import MultiThreadedExecutor
        from rclpy.node import Node
        from std_msgs.msg import String

        from by_your_command.nodes._qos import RELIABLE

        self._action, self._accept, self._string = NavigateToPose, GoalResponse.ACCEPT, String
        self.feedbacks = feedbacks
        self.stamps = ServerStamps()
        self.ack = threading.Event()  # set by whoever consumes the feedback (the provider or the raw client)
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_robot", namespace=namespace, context=self.context)
        self.server = ActionServer(
            self.node,
            NavigateToPose,
            ACTION,
            execute_callback=self._execute,
            goal_callback=self._on_goal,
            callback_group=ReentrantCallbackGroup(),
        )
        self.prompt_text = self.node.create_publisher(String, "prompt_text", RELIABLE)
        self.executor = MultiThreadedExecutor(num_threads=4, context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def _on_goal(self, goal: Any) -> Any:
        self.stamps.goals.append((goal.pose.pose.position.x, time.monotonic()))
        return self._accept

    def _execute(self, handle: Any) -> Any:
        for index in range(self.feedbacks):
            feedback = self._action.Feedback(distance_remaining=float(self.feedbacks - index))
            self.ack.clear()
            self.stamps.feedback.append(time.monotonic())
            handle.publish_feedback(feedback)
            if not self.ack.wait(ACK_WAIT_S):
                self.stamps.unacknowledged += 1
        self.stamps.results.append(time.monotonic())
        handle.succeed()
        return self._action.Result()

    def say(self, text: str) -> None:
        self.prompt_text.publish(self._string(data=text))

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self._thread.join(timeout=5)
        self.server.destroy()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@dataclass
class ClientStamps:
    sent: list[float] = field(default_factory=list)  # just before send_goal_async
    feedback: list[float] = field(default_factory=list)
    results: list[float] = field(default_factory=list)


class RawClient:
    """The baseline: rclpy's own ActionClient on a participant of its own."""

    def __init__(self, namespace: str, robot: Robot) -> None:
        import rclpy
        from by_your_command_msgs.action import NavigateToPose
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self._robot = robot
        self._action = NavigateToPose
        self.stamps = ClientStamps()
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = Node("bench_raw_client", namespace=namespace, context=self.context)
        self.client = ActionClient(self.node, NavigateToPose, ACTION)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._thread = threading.Thread(target=self.executor.spin, daemon=True)
        self._thread.start()

    def ready(self) -> bool:
        return bool(self.client.server_is_ready())

    def send(self) -> None:
        """One goal, sent from the executor's thread."""
        self.executor.create_task(self._send)

    def _send(self) -> None:
        goal = self._action.Goal()
        goal.pose.header.frame_id = "map"
        goal.pose.pose.position.x = BASELINE_X
        goal.pose.pose.orientation.w = 1.0
        self.stamps.sent.append(time.monotonic())
        future = self.client.send_goal_async(goal, feedback_callback=self._on_feedback)
        future.add_done_callback(self._on_goal_response)

    def _on_feedback(self, _feedback: Any) -> None:
        self.stamps.feedback.append(time.monotonic())
        self._robot.ack.set()

    def _on_goal_response(self, future: Any) -> None:
        handle = future.result()
        if handle is not None and handle.accepted:
            handle.get_result_async().add_done_callback(self._on_result)

    def _on_result(self, _future: Any) -> None:
        self.stamps.results.append(time.monotonic())

    def close(self) -> None:
        import rclpy

        self.executor.shutdown()
        self._thread.join(timeout=5)
        self.client.destroy()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


# --- ours: the agent runtime with a scripted provider --------------------------------------------


@dataclass
class ProviderStamps:
    calls: list[float] = field(default_factory=list)  # ToolCall emitted
    progress: list[float] = field(default_factory=list)  # send_tool_progress
    results: list[float] = field(default_factory=list)  # send_tool_results
    outputs: list[str] = field(default_factory=list)  # the results' JSON
    sessions: int = 0
    tools: tuple[str, ...] = ()  # what the last session was offered


class BenchProvider:
    """Calls go_to on every typed turn; answers its result with an empty reply."""

    name = "bench"
    input_sample_rate = 24000
    max_session_s = 3600.0

    def __init__(self, stamps: ProviderStamps, on_progress: Callable[[], None]) -> None:
        self._stamps = stamps
        self._on_progress = on_progress
        self._events: asyncio.Queue[ProviderEvent | None] = asyncio.Queue()
        self._responses = 0

    def _response_id(self) -> str:
        self._responses += 1
        return f"bench-response-{self._responses}"

    async def connect(self, setup: SessionSetup) -> None:
        self._stamps.sessions += 1
        self._stamps.tools = tuple(tool.name for tool in setup.tools)

    async def send_audio(self, pcm: bytes) -> None:
        pass

    async def end_of_turn(self) -> None:
        self._events.put_nowait(ResponseDone(self._response_id(), ResponseStatus.COMPLETED))

    async def send_text(self, text: str) -> None:
        response_id = self._response_id()
        call = ToolCall(response_id, f"call-{response_id}", "go_to", GO_TO)
        self._stamps.calls.append(time.monotonic())
        self._events.put_nowait(call)
        self._events.put_nowait(ResponseDone(response_id, ResponseStatus.COMPLETED))

    async def add_context(self, text: str) -> None:
        pass

    async def send_image(self, jpeg: bytes) -> None:
        pass

    async def send_tool_results(self, results: Sequence[ToolResult]) -> None:
        self._stamps.results.append(time.monotonic())
        self._stamps.outputs += [result.output for result in results]
        self._events.put_nowait(ResponseDone(self._response_id(), ResponseStatus.COMPLETED))

    async def send_tool_progress(self, call_id: str, text: str) -> None:
        self._stamps.progress.append(time.monotonic())
        self._on_progress()

    async def interrupt(self, response_id: str, item_id: str, played_ms: int) -> None:
        pass

    async def close(self) -> None:
        self._events.put_nowait(None)

    async def events(self) -> AsyncIterator[ProviderEvent]:
        while (event := await self._events.get()) is not None:
            yield event


TOOLS_LOGGER = model_tool_calls.__name__  # where the agent logs the robot's tools it was given


class _ToolsSeen(logging.Handler):
    """Notices the agent's log line that it has the robot's tools (the catalog from the bridge)."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.seen = threading.Event()

    def emit(self, record: logging.LogRecord) -> None:
        message = record.getMessage()
        if "the robot's tools:" in message and "go_to" in message:
            self.seen.set()


class Agent:
    """AgentRuntime + BridgePort + BridgeClient on an asyncio loop of their own thread."""

    def __init__(self, url: str, robot: Robot) -> None:
        self.stamps = ProviderStamps()
        self._robot = robot
        self.config: AgentConfig = parse_agent_config(
            {
                "agent_id": "bench_tools",
                "role": "tools",
                "pause_timeout_s": 600.0,
                "conversation_timeout_s": 3600.0,
            }
        )
        self.tools_seen = _ToolsSeen()
        tools_log = logging.getLogger(TOOLS_LOGGER)
        tools_log.setLevel(logging.INFO)  # INFO is not printed: the root logger has no handler
        tools_log.addHandler(self.tools_seen)
        self.loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self._thread.start()
        self.client, self.runtime = self._on_loop(self._build(url)).result(10)
        self.running: Future[None] = self._on_loop(self._run())

    def _on_loop(self, work: Any) -> Future[Any]:
        return asyncio.run_coroutine_threadsafe(work, self.loop)

    async def _build(self, url: str) -> tuple[BridgeClient, AgentRuntime]:
        client = BridgeClient(url)
        port = BridgePort(client, self.config)
        await port.setup()
        runtime = AgentRuntime(self.config, "bench", port, self._provider)
        await client.start()
        return client, runtime

    def _provider(self) -> BenchProvider:
        return BenchProvider(self.stamps, self._robot.ack.set)

    async def _run(self) -> None:
        try:
            await self.runtime.run()
        finally:
            await self.client.close()

    def check(self) -> None:
        if self.running.done():
            self.running.result()  # raises what ended it
            raise RuntimeError("the agent runtime stopped")

    def close(self) -> None:
        if not self.running.done():
            self.loop.call_soon_threadsafe(self.runtime.stop)
        try:
            self.running.result(30)
        finally:
            self.loop.call_soon_threadsafe(self.loop.stop)
            self._thread.join(timeout=5)
            logging.getLogger(TOOLS_LOGGER).removeHandler(self.tools_seen)


# --- the run -------------------------------------------------------------------------------------


@dataclass
class Figures:
    goal: list[float] = field(default_factory=list)
    feedback: list[float] = field(default_factory=list)
    result: list[float] = field(default_factory=list)


def ms(later: float, earlier: float) -> float:
    return 1000.0 * (later - earlier)


class Bench:
    def __init__(self, robot: Robot, raw: RawClient, agent: Agent, bridge: Process) -> None:
        self.robot, self.raw, self.agent, self.bridge = robot, raw, agent, bridge
        self.baseline, self.ours = Figures(), Figures()
        self.missing = 0  # feedback stamps that did not pair up (a feedback lost or coalesced)

    def check(self) -> None:
        self.bridge.check()
        self.agent.check()

    def _goal_at(self, before: int, x: float) -> float:
        def arrived() -> tuple[float, float] | None:
            self.check()
            return self.robot.stamps.goals[before] if len(self.robot.stamps.goals) > before else None

        goal_x, at = wait_until(arrived, WAIT_S, "the goal at the server")
        if goal_x != x:
            raise RuntimeError(f"the server got a goal at x={goal_x}, expected {x}: goals overlap")
        return at

    def _feedback(self, figures: Figures, server_before: int, consumer: list[float], before: int) -> None:
        server = self.robot.stamps.feedback[server_before:]
        got = consumer[before:]
        if len(server) != self.robot.feedbacks or len(got) != len(server):
            self.missing += abs(self.robot.feedbacks - len(got))
            return
        figures.feedback += [ms(b, a) for a, b in zip(server, got, strict=True)]

    def baseline_goal(self, counted: bool) -> None:
        robot, client = self.robot.stamps, self.raw.stamps
        goals, feedback, results = len(robot.goals), len(robot.feedback), len(client.results)
        consumer = len(client.feedback)
        self.raw.send()
        goal_at = self._goal_at(goals, BASELINE_X)

        def done() -> bool:
            self.check()
            return len(client.results) > results

        wait_until(done, WAIT_S, "the baseline's result")
        if counted:
            self.baseline.goal.append(ms(goal_at, client.sent[-1]))
            self._feedback(self.baseline, feedback, client.feedback, consumer)
            self.baseline.result.append(ms(client.results[-1], robot.results[-1]))

    def our_goal(self, counted: bool) -> None:
        robot, provider = self.robot.stamps, self.agent.stamps
        goals, feedback, results = len(robot.goals), len(robot.feedback), len(provider.results)
        consumer, turns = len(provider.progress), self.agent.runtime.counters.turns
        self.robot.say("go to the kitchen")
        goal_at = self._goal_at(goals, OURS_X)

        def done() -> bool:
            self.check()
            # the typed turn ("acting") and the result's turn both over: the next goal starts clean
            return len(provider.results) > results and self.agent.runtime.counters.turns >= turns + 2

        wait_until(done, WAIT_S, "our result at the provider")
        outcome = json.loads(provider.outputs[-1])
        if outcome.get("status") != "succeeded":
            raise RuntimeError(f"the tool call did not succeed: {outcome}")
        if counted:
            self.ours.goal.append(ms(goal_at, provider.calls[-1]))
            self._feedback(self.ours, feedback, provider.progress, consumer)
            self.ours.result.append(ms(provider.results[-1], robot.results[-1]))

    def run(self, trials: int) -> None:
        for index in range(WARMUP + trials):
            counted = index >= WARMUP
            pair = (self.baseline_goal, self.our_goal)
            for step in pair if index % 2 == 0 else reversed(pair):  # neither always goes first
                step(counted)


def start(namespace: str, tmp: Path, feedbacks: int, stack: ExitStack) -> Bench:
    tools = tmp / "tools.yaml"
    tools.write_text(TOOLS, encoding="utf-8")
    robot = Robot(namespace, feedbacks)
    stack.callback(robot.close)
    raw = RawClient(namespace, robot)
    stack.callback(raw.close)
    bridge = Process(
        node_command(
            "ros_ai_bridge", namespace, "port:=0", "diagnostics_period_s:=1.0", f"tools_path:={tools}"
        )
    )
    stack.callback(bridge.stop)

    def listening() -> Any:
        bridge.check()
        return bridge.find(r"listening on 127\.0\.0\.1:(\d+)")

    port = wait_until(listening, 60, "the bridge").group(1)
    agent = Agent(f"ws://127.0.0.1:{port}", robot)
    stack.callback(agent.close)
    bench = Bench(robot, raw, agent, bridge)

    def ready() -> bool:
        bench.check()
        return (
            agent.tools_seen.seen.is_set()
            and robot.prompt_text.get_subscription_count() > 0
            and raw.ready()
            and robot.node.count_clients(f"{namespace}/{ACTION}/_action/send_goal") >= 2  # bridge + raw
        )

    wait_until(ready, 60, "the agent with the robot's tools, the bridge's action client")
    return bench


def table(rows: list[tuple[str, int, tuple[float, float, float], str]]) -> None:
    print()
    print(f"{'figure':50s} {'n':>4s} {'p50 ms':>8s} {'p95 ms':>8s} {'max ms':>8s}  note")
    for name, count, (p50, p95, top), note in rows:
        print(f"{name:50s} {count:4d} {p50:8.2f} {p95:8.2f} {top:8.2f}  {note}")


def stats(values: list[float]) -> tuple[float, float, float]:
    return percentile(values, 50), percentile(values, 95), max(values, default=float("nan"))


def report(bench: Bench, trials: int, feedbacks: int) -> None:
    names = {
        "goal": "tool call -> goal at the server",
        "feedback": "server feedback -> model",
        "result": "server result -> model",
    }
    rows: list[tuple[str, int, tuple[float, float, float], str]] = []
    for key, title in names.items():
        baseline, ours = getattr(bench.baseline, key), getattr(bench.ours, key)
        (o50, o95, omax), (b50, b95, bmax) = stats(ours), stats(baseline)
        added = (o50 - b50, o95 - b95, omax - bmax)
        figure = f"{key}_ms"
        head = {"bench": BENCH, "unit": "ms"}
        print(json.dumps({**head, "figure": f"baseline_raw_rclpy_{figure}", **summary(baseline)}))
        print(json.dumps({**head, "figure": f"ours_agent_bridge_{figure}", **summary(ours)}))
        added_record = {"p50": round(added[0], 2), "p95": round(added[1], 2), "max": round(added[2], 2)}
        extra: dict[str, Any] = {}
        note = "ours - baseline, per percentile"
        if key == "goal":
            meets = added[1] <= GOAL_ADDED_P95_MS
            extra = {"goal_p95_ms": GOAL_ADDED_P95_MS, "meets_goal": meets}
            note += f"; goal p95 <= {GOAL_ADDED_P95_MS:g} ms: {'met' if meets else 'NOT met'}"
        print(json.dumps({**head, "figure": f"added_{figure}", **added_record, **extra}))
        rows += [
            (f"{title}: raw rclpy", len(baseline), stats(baseline), "baseline"),
            (f"{title}: agent + bridge", len(ours), stats(ours), ""),
            (f"{title}: added", len(ours), added, note),
        ]
    print(
        json.dumps(
            {
                "bench": BENCH,
                "figure": "run",
                "value": f"{trials} goals each, {feedbacks} feedback per goal",
                "feedback_unpaired": bench.missing,
                "feedback_unacknowledged": bench.robot.stamps.unacknowledged,
                "sessions": bench.agent.stamps.sessions,
            }
        )
    )
    table(rows)
    print(
        f"\n{trials} goals each (after {WARMUP} warm-up), alternating; {feedbacks} feedback per goal; "
        f"unpaired feedback {bench.missing}, unacknowledged {bench.robot.stamps.unacknowledged}"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=100, help="goals of each kind (baseline, ours)")
    parser.add_argument("--feedbacks", type=int, default=3, help="feedback messages per goal")
    args = parser.parse_args()
    if args.trials < 1 or args.feedbacks < 1:
        parser.error("--trials and --feedbacks must be at least 1")
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    namespace = f"/bench_{BENCH}_{os.getpid()}"
    with ExitStack() as stack:
        tmp = Path(stack.enter_context(tempfile.TemporaryDirectory()))
        bench = start(namespace, tmp, args.feedbacks, stack)
        bench.run(args.trials)
        report(bench, args.trials, args.feedbacks)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""demo_robot: a pretend robot for the demo, the tests and the benches (docs/tools.md).

It serves what the agents' robot tools call, with Nav2's names and shapes:
- the action `navigate_to_pose` (by_your_command_msgs/action/NavigateToPose): drives in a straight
  line toward the goal at `speed_mps`, publishing feedback `feedback_rate_hz` times a second;
  honours cancel; a newer goal preempts the current one (aborted, like Nav2); refuses goals whose
  frame is not `frame_id` or whose position is not finite or farther than `max_distance_m`;
- the services `dock` and `battery_status` (by_your_command_msgs/srv/Trigger).
Names are relative: in the root namespace they are /navigate_to_pose, /dock and /battery_status.
Test knobs: `reject_goals`, `abort_after_s`, `accept_delay_s`, `service_delay_s`.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any

from builtin_interfaces.msg import Duration
from by_your_command_msgs.action import NavigateToPose
from by_your_command_msgs.srv import Trigger
from geometry_msgs.msg import PoseStamped
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.action.server import ServerGoalHandle
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node

from by_your_command.nodes._params import declare_config
from by_your_command.nodes._runtime import run_node

# Threads of the executor: a goal being driven, a delayed goal answer and a delayed service call
# each hold one while they wait.
EXECUTOR_THREADS = 6
ABORT_ERROR_CODE = 1  # Nav2 has its own codes (UNKNOWN = 9000...); the demo needs only "it failed"
PREEMPTED_ERROR_CODE = 2


@dataclass(frozen=True)
class DemoRobotParams:
    speed_mps: float = field(default=0.5, metadata={"help": "driving speed toward the goal (m/s)"})
    feedback_rate_hz: float = field(default=5.0, metadata={"help": "feedback messages per second"})
    frame_id: str = field(default="map", metadata={"help": "the only frame goals may be given in"})
    max_distance_m: float = field(
        default=100.0, metadata={"help": "goals farther than this from the robot are refused"}
    )
    start_x: float = field(default=0.0, metadata={"help": "where the robot starts (m)"})
    start_y: float = field(default=0.0, metadata={"help": "where the robot starts (m)"})
    dock_x: float = field(default=0.0, metadata={"help": "where the dock is (m)"})
    dock_y: float = field(default=0.0, metadata={"help": "where the dock is (m)"})
    battery_percent: float = field(default=87.0, metadata={"help": "what battery_status reports"})
    reject_goals: bool = field(default=False, metadata={"help": "tests: refuse every goal"})
    abort_after_s: float = field(
        default=0.0, metadata={"help": "tests: > 0 aborts every goal after driving this long"}
    )
    accept_delay_s: float = field(
        default=0.0, metadata={"help": "tests: answer a goal request only after this long"}
    )
    service_delay_s: float = field(
        default=0.0, metadata={"help": "tests: answer dock and battery_status only after this long"}
    )

    def __post_init__(self) -> None:
        for name in ("speed_mps", "feedback_rate_hz", "max_distance_m"):
            value = getattr(self, name)
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive number, got {value}")
        for name in ("abort_after_s", "accept_delay_s", "service_delay_s", "battery_percent"):
            value = getattr(self, name)
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        for name in ("start_x", "start_y", "dock_x", "dock_y"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{name} must be finite")
        if not self.frame_id:
            raise ValueError("frame_id must not be empty")


def goal_problem(pose: PoseStamped, frame_id: str, x: float, y: float, max_distance_m: float) -> str:
    """Why a goal pose is refused, or "" when it is fine."""
    if pose.header.frame_id != frame_id:
        return f"frame {pose.header.frame_id!r} is not {frame_id!r}"
    position, orientation = pose.pose.position, pose.pose.orientation
    values = (position.x, position.y, position.z, orientation.x, orientation.y, orientation.z, orientation.w)
    if not all(math.isfinite(value) for value in values):
        return "the pose is not finite"
    distance = math.hypot(position.x - x, position.y - y)
    if distance > max_distance_m:
        return f"the goal is {distance:.1f} m away (at most {max_distance_m:g} m)"
    return ""


def _duration(seconds: float) -> Duration:
    seconds = max(seconds, 0.0)
    whole = int(seconds)
    return Duration(sec=whole, nanosec=int((seconds - whole) * 1e9))


class DemoRobot(Node):
    def __init__(self) -> None:
        super().__init__("demo_robot")
        self.params = declare_config(self, DemoRobotParams)
        self._lock = threading.Lock()  # the pose and the active goal, shared by executor threads
        self._x, self._y = self.params.start_x, self.params.start_y
        self._active: ServerGoalHandle | None = None
        self._stopping = threading.Event()
        group = ReentrantCallbackGroup()
        self._server = ActionServer(
            self,
            NavigateToPose,
            "navigate_to_pose",
            execute_callback=self._execute,
            goal_callback=self._on_goal,
            cancel_callback=lambda _request: CancelResponse.ACCEPT,
            callback_group=group,
        )
        self.create_service(Trigger, "dock", self._dock, callback_group=group)
        self.create_service(Trigger, "battery_status", self._battery, callback_group=group)
        self.get_logger().info(
            f"demo_robot ready at ({self._x:g}, {self._y:g}) in {self.params.frame_id!r}, "
            f"{self.params.speed_mps:g} m/s, feedback at {self.params.feedback_rate_hz:g} Hz"
        )

    # --- navigate_to_pose ------------------------------------------------------------------------

    def _on_goal(self, goal: Any) -> GoalResponse:
        if self.params.accept_delay_s:
            self.get_logger().info(f"answering a goal request in {self.params.accept_delay_s:g} s")
            self._stopping.wait(self.params.accept_delay_s)
        if self.params.reject_goals:
            self.get_logger().info("goal refused: reject_goals is set")
            return GoalResponse.REJECT
        with self._lock:
            problem = goal_problem(
                goal.pose, self.params.frame_id, self._x, self._y, self.params.max_distance_m
            )
        if problem:
            self.get_logger().warning(f"goal refused: {problem}")
            return GoalResponse.REJECT
        return GoalResponse.ACCEPT

    def _execute(self, handle: ServerGoalHandle) -> NavigateToPose.Result:
        with self._lock:
            previous, self._active = self._active, handle
        if previous is not None:
            self.get_logger().info("a newer goal preempts the current one")
        target = handle.request.pose
        period = 1.0 / self.params.feedback_rate_hz
        started = time.monotonic()
        last = started
        position = target.pose.position
        self.get_logger().info(f"driving to ({position.x:g}, {position.y:g}) in {target.header.frame_id!r}")
        while True:
            now = time.monotonic()
            with self._lock:
                preempted = self._active is not handle
                remaining = self._step(target, self.params.speed_mps * (now - last))
            last = now
            if handle.is_cancel_requested:
                handle.canceled()
                self.get_logger().info("goal cancelled")
                return self._finish(handle, NavigateToPose.Result(error_msg="cancelled"))
            if preempted or self._stopping.is_set():
                handle.abort()
                reason = "preempted by a newer goal" if preempted else "the robot is shutting down"
                return NavigateToPose.Result(error_code=PREEMPTED_ERROR_CODE, error_msg=reason)
            if self.params.abort_after_s and now - started >= self.params.abort_after_s:
                handle.abort()
                self.get_logger().info("goal aborted (abort_after_s)")
                return self._finish(
                    handle, NavigateToPose.Result(error_code=ABORT_ERROR_CODE, error_msg="aborted")
                )
            if remaining <= 0.0:
                handle.succeed()
                self.get_logger().info("goal reached")
                return self._finish(handle, NavigateToPose.Result())
            handle.publish_feedback(self._feedback(target, now - started, remaining))
            self._stopping.wait(period)

    def _step(self, target: PoseStamped, travel: float) -> float:
        """Move up to `travel` metres toward the target; return the distance still to go."""
        dx, dy = target.pose.position.x - self._x, target.pose.position.y - self._y
        distance = math.hypot(dx, dy)
        if distance <= travel or distance == 0.0:
            self._x, self._y = target.pose.position.x, target.pose.position.y
            return 0.0
        self._x += dx / distance * travel
        self._y += dy / distance * travel
        return distance - travel

    def _feedback(self, target: PoseStamped, elapsed: float, remaining: float) -> NavigateToPose.Feedback:
        feedback = NavigateToPose.Feedback()
        feedback.current_pose.header.frame_id = self.params.frame_id
        feedback.current_pose.header.stamp = self.get_clock().now().to_msg()
        with self._lock:
            feedback.current_pose.pose.position.x, feedback.current_pose.pose.position.y = self._x, self._y
        feedback.current_pose.pose.orientation = target.pose.orientation
        feedback.navigation_time = _duration(elapsed)
        feedback.estimated_time_remaining = _duration(remaining / self.params.speed_mps)
        feedback.distance_remaining = remaining
        return feedback

    def _finish(self, handle: ServerGoalHandle, result: NavigateToPose.Result) -> NavigateToPose.Result:
        with self._lock:
            if self._active is handle:
                self._active = None
        return result

    # --- services --------------------------------------------------------------------------------

    def _dock(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.params.service_delay_s:
            self._stopping.wait(self.params.service_delay_s)
        with self._lock:
            if self._active is not None:
                response.success, response.message = False, "busy: a navigation goal is active"
                return response
            self._x, self._y = self.params.dock_x, self.params.dock_y
        response.success, response.message = True, "docked"
        self.get_logger().info("docked")
        return response

    def _battery(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        if self.params.service_delay_s:
            self._stopping.wait(self.params.service_delay_s)
        response.success = True
        response.message = f"battery at {self.params.battery_percent:.0f}%"
        return response

    def before_shutdown(self) -> None:
        self._stopping.set()  # a goal being driven ends (aborted) instead of holding a thread

    def destroy_node(self) -> None:
        self._stopping.set()
        self._server.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(DemoRobot, args, threads=EXECUTOR_THREADS)


if __name__ == "__main__":
    main()

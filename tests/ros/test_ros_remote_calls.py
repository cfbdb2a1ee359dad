"""A fleet's calls to its robots' managers (sm_bt.ros.remote_robots.RobotCalls): each call ends once, by
its answer, its timeout, its abandonment when the robot is out of reach, or the robot's own word of the
request it made (its answer lost: sm_bt.ros.remote_requests.RobotRequests), whatever order they come in;
a change to a manager DDS vouches for asks the graph only the first time since the robot was in reach.
Clients are fakes here (what a call does on the wire is tests/ros/test_ros_remote_reference_like.py's and
test_ros_fleet.py's)."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from hypothesis import given
from hypothesis import strategies as st
from hypothesis_profiles import examples

from sm_bt.engine.backend import CallResult
from sm_bt.engine.clock import VirtualClock
from sm_bt.model.types import FLEET_REQUESTER
from sm_bt.ros.remote_requests import ANSWER_GRACE, RobotRequests
from sm_bt.ros.remote_robots import Robot, RobotCalls

TIMEOUT = 5.0


class FakeFuture:
    def __init__(self) -> None:
        self._callbacks: list[Callable[[Any], None]] = []
        self._result: Any = None

    def add_done_callback(self, callback: Callable[[Any], None]) -> None:
        self._callbacks.append(callback)

    def result(self) -> Any:
        return self._result

    def answer(self, response: Any) -> None:
        self._result = response
        for callback in self._callbacks:
            callback(self)


class FakeClient:
    """A service client: ``ready`` is what the graph shows; ``futures`` the calls sent."""

    def __init__(self, ready: bool = True) -> None:
        self.ready = ready
        self.asked_graph = 0
        self.futures: list[FakeFuture] = []
        self.removed: list[FakeFuture] = []

    def service_is_ready(self) -> bool:
        self.asked_graph += 1
        return self.ready

    def call_async(self, request: Any) -> FakeFuture:
        future = FakeFuture()
        self.futures.append(future)
        return future

    def remove_pending_request(self, future: FakeFuture) -> None:
        self.removed.append(future)


def _robot(client: FakeClient, *, present: bool = True, lively: bool = True) -> Robot:
    robot = Robot("robot1", "/robot1/pilot", client, client, client, client, False, client, client, None)
    robot.present, robot.lively = present, lively
    return robot


def _calls() -> tuple[VirtualClock, RobotCalls]:
    clock = VirtualClock()
    return clock, RobotCalls(clock, threading.Lock(), TIMEOUT)  # type: ignore[arg-type]


class Ends:
    def __init__(self) -> None:
        self.answers: list[Any] = []
        self.failures: list[str] = []
        self.told: list[Any] = []

    def answered(self, response: Any) -> None:
        self.answers.append(response)

    def failed(self, why: str) -> None:
        self.failures.append(why)

    def settled(self, result: Any) -> None:
        self.told.append(result)

    @property
    def count(self) -> int:
        return len(self.answers) + len(self.failures) + len(self.told)


class Outcome:
    """A robot's RequestOutcome."""

    def __init__(self, number: int, description: str, outcome: str = "succeeded", reason: str = "") -> None:
        self.request, self.description, self.requester = number, description, FLEET_REQUESTER
        self.outcome, self.reason = outcome, reason


def test_a_change_to_a_vouched_for_manager_asks_the_graph_once_until_the_robot_was_out_of_reach() -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    ends = Ends()
    for _ in range(3):
        calls.change(robot, client, "request", "change_mode FAST", ends.answered, ends.failed)
    assert (client.asked_graph, len(client.futures)) == (1, 3)
    calls.abandon(robot, "out of reach")  # back later, perhaps as another process: asked again
    calls.change(robot, client, "request", "change_mode FAST", ends.answered, ends.failed)
    assert (client.asked_graph, len(client.futures)) == (2, 4)
    # Not vouched for (DDS lost its lease, or it is not read yet): the graph is asked each time, and no
    # server fails the call at once.
    client.ready = False
    for doubted in (_robot(client, lively=False), _robot(client, present=False)):
        doubted.seen_ready.add(client)
        calls.change(doubted, client, "request", "change_mode FAST", ends.answered, ends.failed)
    clock.advance(0.0)
    assert client.asked_graph == 4 and len(client.futures) == 4
    assert ends.failures[-2:] == ["/robot1/pilot: no manager serves it (change_mode FAST)"] * 2


def test_abandoned_changes_fail_once_with_the_reason_and_probes_and_answered_calls_are_not_touched() -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    changes, answered, probe = Ends(), Ends(), Ends()
    calls.change(robot, client, "request", "change_mode FAST", changes.answered, changes.failed)
    calls.change(robot, client, "request", "change_mode FAST", answered.answered, answered.failed)
    calls.call(robot, client, "request", "get_state", probe.answered, probe.failed)
    client.futures[1].answer("accepted")
    calls.abandon(robot, "no answer from the manager of robot1")
    calls.abandon(robot, "again")
    clock.advance(TIMEOUT + 1.0)  # the timeouts of the ended ones do nothing
    assert changes.failures == ["no answer from the manager of robot1"] and not changes.answers
    assert client.removed == [client.futures[0], client.futures[2]]  # the abandoned one, the probe timed out
    assert answered.answers == ["accepted"] and not answered.failures
    assert probe.failures == ["the manager of robot1 did not answer get_state within 5 s"]
    assert robot.owed == {}
    client.futures[0].answer("late")  # an answer after it was given up is dropped
    assert not changes.answers


@examples(200)
@given(st.permutations(["answer", "timeout", "abandon", "answer again"]))
def test_a_call_ends_exactly_once_whichever_of_its_ends_comes_first(order: list[str]) -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    ends = Ends()
    calls.change(robot, client, "request", "change_mode FAST", ends.answered, ends.failed)
    for end in order:
        if end.startswith("answer"):
            client.futures[0].answer(end)
        elif end == "timeout":
            clock.advance(TIMEOUT)
        else:
            calls.abandon(robot, "out of reach")
    first = order[0]
    assert len(ends.answers) + len(ends.failures) == 1, (ends.answers, ends.failures)
    if first.startswith("answer"):
        assert ends.answers == [first]
    else:
        assert ends.failures == ["the manager of robot1 did not answer change_mode FAST within 5 s"
                                 if first == "timeout" else "out of reach"]
    assert robot.owed == {}


def test_a_request_whose_answer_is_lost_ends_with_the_outcome_its_robot_told_and_only_the_call_that_asked_it(
        ) -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    requests = RobotRequests("robot1", clock, 60.0, settle=lambda told_by, result: calls.settle(robot, told_by, result))
    night, other = Ends(), Ends()
    calls.change(robot, client, "request", "change_mode NIGHT", night.answered, night.failed, told=night.settled,
                 told_by=("change_mode", "NIGHT"))
    calls.call(robot, client, "request", "get_state", other.answered, other.failed)  # a probe: not owed
    requests.ended(Outcome(7, "change_mode pilot DAY"))  # another request's (a fleet before a restart)
    requests.ended(Outcome(8, "change_mode pilot NIGHT", "failed", "amcl: activate failed"))
    clock.advance(ANSWER_GRACE - 0.01)
    assert night.count == 0, "its answer may still come"
    clock.advance(0.02)
    assert night.told == [CallResult(False, "its manager's request #8 failed: amcl: activate failed")]
    assert client.removed == [client.futures[0]] and robot.owed == {}
    client.futures[0].answer("accepted as #8, late")  # ignored: it ended
    clock.advance(TIMEOUT)
    assert night.count == 1 and other.failures  # the probe timed out as ever


def test_an_outcome_whose_answer_comes_within_the_grace_ends_its_call_through_the_answer_once() -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    settled: list[Any] = []

    def settle(told_by: tuple[str, str], result: Any) -> bool:
        settled.append(result)
        return calls.settle(robot, told_by, result)

    requests = RobotRequests("robot1", clock, 60.0, settle=settle)
    night = Ends()
    done: list[Any] = []

    def answered(response: Any) -> None:  # as RemoteBackend's: the answer numbers the request
        requests.accepted(response, "change_mode NIGHT", done.append)

    calls.change(robot, client, "request", "change_mode NIGHT", answered, night.failed, told=night.settled,
                 told_by=("change_mode", "NIGHT"))
    requests.ended(Outcome(3, "change_mode pilot NIGHT"))
    client.futures[0].answer(3)
    clock.advance(ANSWER_GRACE + TIMEOUT + 60.0)
    assert done == [CallResult(True)] and night.count == 0 and settled == []


@examples(200)
@given(st.permutations(["answer", "timeout", "abandon", "told", "answer again"]))
def test_a_call_that_may_be_told_ends_exactly_once_whichever_of_its_ends_comes_first(order: list[str]) -> None:
    clock, calls = _calls()
    client = FakeClient()
    robot = _robot(client)
    ends = Ends()
    calls.change(robot, client, "request", "change_mode FAST", ends.answered, ends.failed, told=ends.settled,
                 told_by=("change_mode", "FAST"))
    for end in order:
        if end.startswith("answer"):
            client.futures[0].answer(end)
        elif end == "timeout":
            clock.advance(TIMEOUT)
        elif end == "told":
            assert calls.settle(robot, ("change_mode", "FAST"), "told") is (order[0] == "told")
        else:
            calls.abandon(robot, "out of reach")
    assert ends.count == 1, (ends.answers, ends.failures, ends.told)
    assert robot.owed == {}
    if order[0] == "told":
        assert ends.told == ["told"]

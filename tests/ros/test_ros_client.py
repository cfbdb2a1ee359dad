"""``sm-bt mode ...``/``sm-bt state ...`` against ``sm-bt manager`` on ROS 2, as a person uses them.

The manager runs in its own process, the pilot's nodes in another; the commands run through
``sm_bt.cli.main`` here (their own rclpy context each time). Checked: getting and setting modes
and states with confirmation and its time, the modes offered, a node's own lifecycle service,
usage errors with the closest names for parts, modes and transitions (exit 2), a change that is
not confirmed in time (exit 1, where the part is), and no manager at all (exit 1 within the
timeout, what to check), a change the manager fails (exit 1 at once, the manager's reason).
"""

from __future__ import annotations

import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from ros_processes import ManagerProcess, RosContext, Starter

from sm_bt.cli import main

pytestmark = pytest.mark.ros


def sm_bt(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.long
def test_mode_and_state_commands_drive_the_pilot_and_confirm_each_change(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager("--grace-period", "0.3")
    node_processes("pilot")
    manager.ready()
    # Serving comes first; the pilot is unknown until the manager has asked every node where it is.
    deadline = time.monotonic() + 15.0
    while (state := sm_bt(capsys, "state", "get", "pilot")[1]) == "pilot: unknown\n" and time.monotonic() < deadline:
        time.sleep(0.2)
    assert state == "pilot: unconfigured\n"
    assert sm_bt(capsys, "mode", "get", "pilot")[1] == "pilot: (no mode: not active)\n"

    code, out, err = sm_bt(capsys, "state", "set", "pilot", "configure", "--wait")
    assert (code, err) == (0, "") and re.fullmatch(r"pilot: inactive \d+\.\d\d s after the request\n", out), out
    code, out, err = sm_bt(capsys, "mode", "set", "pilot", "f_normal_mode", "--wait")
    assert (code, err) == (0, "")
    assert re.fullmatch(r"pilot: f_normal_mode confirmed (\d+\.\d\d) s after the request\n", out), out
    assert sm_bt(capsys, "mode", "get", "pilot")[1] == "pilot: f_normal_mode\n"
    assert sm_bt(capsys, "state", "get", "amcl")[1] == "amcl: active\n"  # a node: its own service

    code, out, _ = sm_bt(capsys, "mode", "list", "pilot")
    assert code == 0 and out.splitlines() == ["__DEFAULT__", "f_degraded_mode", "f_energy_saving_mode",
                                              "f_normal_mode", "f_performance_mode", "f_slow_mode"]
    assert sm_bt(capsys, "modes", "pilot", "--ros")[1] == out

    # Without --wait: accepted, then done a moment later.
    assert sm_bt(capsys, "mode", "set", "pilot", "f_degraded_mode") == (0, "pilot: change to f_degraded_mode "
                                                                            "accepted\n", "")
    deadline = time.monotonic() + 5.0
    while sm_bt(capsys, "mode", "get", "pilot")[1] != "pilot: f_degraded_mode\n":
        assert time.monotonic() < deadline, "f_degraded_mode never reached"
    assert manager.lines("change_mode pilot f_degraded_mode", "succeeded")

    # A node the manager manages: a direct transition is refused, unless forced; then --wait says
    # what holds once the manager had its say (it put the node back: its target is active).
    code, out, err = sm_bt(capsys, "state", "set", "amcl", "deactivate", "--wait")
    assert (code, out) == (1, "") and err.startswith("sm-bt: error: amcl is a node that a mode manager manages: "), err
    assert sm_bt(capsys, "state", "get", "amcl")[1] == "amcl: active\n"  # nothing was sent
    code, out, err = sm_bt(capsys, "state", "set", "amcl", "deactivate", "--wait", "--force")
    assert re.fullmatch(r"amcl: inactive \d+\.\d\d s after the request\n", out), (out, err)
    assert (code, err) == (1, "sm-bt: error: amcl: then active again: its mode manager put it back\n"), err


def test_names_that_are_not_served_are_usage_errors_with_the_closest_name(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager()
    node_processes("pilot")
    manager.ready()
    started = time.monotonic()
    assert sm_bt(capsys, "mode", "set", "pilto", "f_normal_mode") == (
        2, "", "sm-bt mode: error: no manager serves the part 'pilto' (did you mean 'pilot'?)\n")
    assert time.monotonic() - started < 8.0  # found out from the graph, not after the 10 s timeout
    assert sm_bt(capsys, "mode", "set", "pilot", "f_nrmal_mode") == (
        2, "", "sm-bt mode: error: pilot has no mode 'f_nrmal_mode' (did you mean 'f_normal_mode'?)\n")
    assert sm_bt(capsys, "state", "set", "pilot", "configur") == (
        2, "", "sm-bt state: error: 'configur' is not a transition (did you mean 'configure'?)\n")
    assert not manager.lines("started")  # nothing was asked of the manager


def test_a_change_not_confirmed_in_time_fails_and_says_where_the_part_is(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager()
    # The timeout bounds the call too: a fresh client may find the manager's service only after a
    # few seconds on a loaded machine (DDS discovery), so it is longer than that, and the
    # transitions longer still.
    node_processes("pilot", "--transition-delay", "8")
    manager.ready()
    code, out, err = sm_bt(capsys, "state", "set", "pilot", "configure", "--wait", "--timeout", "4")
    assert (code, out) == (1, "")
    assert re.fullmatch(r"sm-bt: error: not confirmed within 4 s: pilot is \w+, not inactive\n", err), err


def test_a_change_the_manager_fails_ends_the_wait_at_once_with_its_reason(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    """sm-bt manager tells a failure on /diagnostics: --wait ends then, not at its own timeout."""
    manager = start_manager("--request-timeout", "1")
    node_processes("pilot", "--transition-delay", "3")
    manager.ready()
    started = time.monotonic()
    code, out, err = sm_bt(capsys, "mode", "set", "pilot", "f_normal_mode", "--wait", "--timeout", "30")
    took = time.monotonic() - started
    assert (code, out) == (1, "")
    # Where the pilot is then: no mode, or unknown while its nodes are still in their 3 s configuring
    # (which one depends on when the manager last heard of them; a fresh-clone run saw the second).
    assert re.fullmatch(r"sm-bt: error: the manager says request #\d+ change_mode pilot f_normal_mode failed: .*"
                        r"timed out.*: pilot is in mode '(\(none\)|unknown)', not 'f_normal_mode'\n", err), err
    assert took < 15.0, f"the wait ended {took:.1f} s after the request, at its timeout rather than the failure"
    assert manager.lines("change_mode pilot f_normal_mode", "failed")


def test_only_the_failure_of_the_request_waited_for_ends_a_wait() -> None:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

    from sm_bt.ros.client import _Watched

    def status(part: str, last: str, outcome: str, node: bool = False) -> DiagnosticStatus:
        values = {"last_request": last, "last_request_outcome": outcome, "last_request_reason": "timed out"}
        if node:
            values["reachable"] = "true"
        return DiagnosticStatus(hardware_id=part, values=[KeyValue(key=k, value=v) for k, v in values.items()])

    mode = _Watched("pilot", "change_mode pilot f_normal_mode")
    message = DiagnosticArray(status=[status("amcl", "#3 change_mode pilot f_normal_mode", "failed", node=True),
                                      status("pilot", "#4 change_mode pilot f_normal_mode", "running")])
    assert mode.failures(message) == []
    message.status[1] = status("pilot", "#4 change_mode pilot f_slow_mode", "failed")
    assert mode.failures(message) == []
    message.status[1] = status("pilot", "#4 change_mode pilot f_normal_mode", "failed")
    assert mode.failures(message) == ["the manager says request #4 change_mode pilot f_normal_mode failed: timed out"]
    # A node's own change_state service was asked: the manager's last request of that node is another one.
    state = _Watched("amcl", "change_state amcl configure", systems_only=True)
    assert state.failures(DiagnosticArray(status=[status("amcl", "#2 change_state amcl configure", "failed",
                                                         node=True)])) == []
    assert state.failures(DiagnosticArray(status=[status("amcl", "#2 change_state amcl configure", "failed")]))


def test_with_no_manager_the_commands_say_what_to_check_within_the_timeout(
        capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROS_DOMAIN_ID", "231")  # a domain where this test started nothing
    started = time.monotonic()
    code, out, err = sm_bt(capsys, "mode", "get", "pilot", "--timeout", "1.5")
    assert time.monotonic() - started < 6.0
    assert (code, out) == (1, "")
    assert err == ("sm-bt: error: nothing answers /pilot/get_mode within 1.5 s: is a mode manager (`sm-bt manager "
                   "MODEL`) running, with the same ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as this shell?\n")
    # A state may be a node's own: both are said (with nothing running, nothing tells which amcl is).
    code, out, err = sm_bt(capsys, "state", "get", "amcl", "--timeout", "1.5")
    assert (code, out) == (1, "")
    assert err == ("sm-bt: error: nothing answers /amcl/get_state within 1.5 s: if amcl is a node, is it running (its "
                   "own lifecycle service answers this)? If a system, is its mode manager (`sm-bt manager MODEL`) "
                   "running? Either with the same ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE as this shell?\n")


def test_a_system_whose_manager_answers_one_service_late_is_not_called_a_node(
        ros_context: RosContext, capsys: pytest.CaptureFixture[str]) -> None:
    """A stand-in manager serves pilot as a system but its change_state does not show up in time (as
    when a loaded machine makes discovery or the answer late): the message said "pilot is a node",
    which it is not."""
    from lifecycle_msgs.srv import GetAvailableStates
    from system_modes_msgs.srv import GetMode

    node = ros_context.node
    node.create_service(GetMode, "/pilot/get_mode", lambda request, response: response)
    node.create_service(GetAvailableStates, "/pilot/get_available_states", lambda request, response: response)
    code, out, err = sm_bt(capsys, "state", "set", "pilot", "configure", "--timeout", "1")
    assert (code, out) == (1, "")
    assert "pilot is a system, and its mode manager answers get_mode but not change_state in time" in err, err


def test_a_node_that_does_not_answer_is_told_apart_from_a_missing_manager(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager()
    node_processes("pilot", "--only", "controller_server")
    manager.ready()
    code, out, err = sm_bt(capsys, "state", "get", "amcl", "--timeout", "1.5")
    assert (code, out) == (1, "")
    assert err == ("sm-bt: error: nothing answers /amcl/get_state within 1.5 s: amcl is a node, and its mode manager "
                   "answers but the node does not: it is not running, or the network to it is down (`sm-bt mode get "
                   "amcl` shows what the manager knows)\n"), err
    code, out, err = sm_bt(capsys, "state", "get", "controller_server")
    assert out == "controller_server: unconfigured\n", (code, err)


@pytest.mark.long
def test_monitor_next_to_a_running_manager_watches_and_refuses_to_act(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Two managers acting on the same nodes undo each other's changes: the monitor's --change is
    refused (it made the change itself, silently fighting the manager), watching still works."""
    manager = start_manager()
    node_processes("pilot")
    manager.ready()
    code, out, err = sm_bt(capsys, "monitor", "pilot", "--ros", "--change", "pilot=configure", "--once")
    assert code == 1
    assert ("sm-bt: error: a mode manager already serves pilot, amcl, controller_server, pointcloud_to_laser, "
            "laser_resender (/pilot/change_mode): next to it, sm-bt monitor --ros only watches; make the changes "
            "through that manager, e.g. `sm-bt state set pilot configure --wait`") in err
    assert sm_bt(capsys, "state", "get", "amcl")[1] == "amcl: unconfigured\n"  # nothing was touched
    assert not manager.lines("started")
    assert sm_bt(capsys, "state", "set", "pilot", "configure", "--wait")[0] == 0
    code, out, err = sm_bt(capsys, "monitor", "pilot", "--ros", "--once", "--duration", "5")
    assert code == 0, err
    # The targets are the manager's (its request topics): the table is what that manager has.
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.split()[:1] in (["amcl"], ["pilot"])}
    assert rows["amcl"] == ["amcl", "inactive", "inactive"], out
    assert rows["pilot"] == ["pilot", "inactive", "inactive(*)"], out


def test_monitor_with_no_node_answering_says_so_and_fails(capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = sm_bt(capsys, "monitor", "pilot", "--ros", "--once", "--duration", "2")
    assert code == 1 and out == ""
    assert err.startswith("sm-bt: error: nothing answered: none of the model's 4 nodes was reachable within 2."), err
    assert "ROS_DOMAIN_ID=" in err


def test_a_transition_is_sent_with_its_id_and_its_label(
        ros_context: RosContext, capsys: pytest.CaptureFixture[str]) -> None:
    """The reference's mode_manager reads only the id (a label-only request is id 0, ``create``,
    which it forwards to every node); lifecycle nodes and sm-bt manager read the label. A stand-in
    system records what arrives; ``shutdown``'s id depends on the start state, which is asked."""
    from lifecycle_msgs.msg import State
    from lifecycle_msgs.srv import ChangeState, GetAvailableStates, GetState

    received: list[tuple[int, str]] = []

    def change_state(request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        received.append((request.transition.id, request.transition.label))
        response.success = True
        return response

    def get_state(request: GetState.Request, response: GetState.Response) -> GetState.Response:
        response.current_state = State(id=State.PRIMARY_STATE_ACTIVE, label="active")
        return response

    node = ros_context.node
    node.create_service(ChangeState, "/pilot/change_state", change_state)
    node.create_service(GetState, "/pilot/get_state", get_state)
    node.create_service(GetAvailableStates, "/pilot/get_available_states", lambda request, response: response)
    for transition in ("configure", "activate", "deactivate", "cleanup", "shutdown"):
        assert sm_bt(capsys, "state", "set", "pilot", transition, "--timeout", "5") == (
            0, f"pilot: {transition} accepted\n", "")
    assert received == [(1, "configure"), (3, "activate"), (4, "deactivate"), (2, "cleanup"), (7, "shutdown")]


def test_a_wait_hears_the_event_of_a_transition_undone_before_the_wait_starts(ros_context: RosContext) -> None:
    """A managed node's forced transition may be done, told and undone by its manager before a
    wait's own subscription is matched: the client listens from before the request. A stand-in
    node tells ``inactive`` as soon as a listener is there, while its state stays ``active``."""
    from lifecycle_msgs.msg import State, TransitionEvent
    from lifecycle_msgs.srv import ChangeState, GetState

    from sm_bt.ros.client import ModeClient, NotConfirmed

    node = ros_context.node
    events = node.create_publisher(TransitionEvent, "/amcl/transition_event", 10)

    def change_state(request: ChangeState.Request, response: ChangeState.Response) -> ChangeState.Response:
        deadline = time.monotonic() + 1.0  # the transition takes as long as discovery, at most 1 s
        while events.get_subscription_count() == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        events.publish(TransitionEvent(start_state=State(id=State.TRANSITION_STATE_DEACTIVATING, label="deactivating"),
                                       goal_state=State(id=State.PRIMARY_STATE_INACTIVE, label="inactive")))
        response.success = True
        return response

    def get_state(request: GetState.Request, response: GetState.Response) -> GetState.Response:
        response.current_state = State(id=State.PRIMARY_STATE_ACTIVE, label="active")  # already put back
        return response

    node.create_service(ChangeState, "/amcl/change_state", change_state)
    node.create_service(GetState, "/amcl/get_state", get_state)
    with ModeClient(timeout=3.0, context=ros_context.context, node_name="listening") as client:
        client.listen("amcl", "state")
        assert client.change_state("amcl", "deactivate")
        assert 0.0 <= client.wait_for_state("amcl", "deactivate", client.sent) < 1.0
    with ModeClient(timeout=3.0, context=ros_context.context, node_name="not_listening") as client:
        assert client.change_state("amcl", "deactivate")  # told before the wait's subscription was there
        with pytest.raises(NotConfirmed, match="amcl is active, not inactive"):
            client.wait_for_state("amcl", "deactivate", client.sent)


def test_a_dry_run_asks_the_manager_what_a_change_would_do_and_changes_nothing(
        start_manager: Callable[..., ManagerProcess], node_processes: Starter,
        capsys: pytest.CaptureFixture[str]) -> None:
    manager = start_manager()
    node_processes("pilot")
    manager.ready()
    deadline = time.monotonic() + 15.0
    while sm_bt(capsys, "state", "get", "pilot")[1] != "pilot: unconfigured\n" and time.monotonic() < deadline:
        time.sleep(0.2)
    code, out, err = sm_bt(capsys, "mode", "set", "pilot", "f_normal_mode", "--dry-run")
    assert (code, err) == (0, "")
    assert out.splitlines() == [
        "change_mode pilot f_normal_mode: 7 calls", "  pilot -> active.f_normal_mode",
        "    amcl: unconfigured -> active.__DEFAULT__: configure, activate",
        "    controller_server: unconfigured -> active.__DEFAULT__: configure, activate",
        "    pointcloud_to_laser: unconfigured -> inactive: configure",
        "    laser_resender: unconfigured -> active.__DEFAULT__: configure, activate"]
    assert sm_bt(capsys, "state", "get", "pilot")[1] == "pilot: unconfigured\n"  # nothing was done
    assert not manager.lines("change_mode pilot f_normal_mode")
    # A node's change, through the same service of the node's part.
    code, out, _ = sm_bt(capsys, "mode", "set", "amcl", "__DEFAULT__", "--dry-run")
    assert code == 0 and out.startswith("change_mode amcl __DEFAULT__: 2 calls")


def test_a_model_with_remote_parts_and_nodes_is_refused_on_ros_with_what_to_do(tmp_path: Path) -> None:
    """A fleet manager drives remote parts only: a model that mixes them with nodes is refused at
    once, before anything is made, naming both."""
    from sm_bt.model import load_model
    from sm_bt.model.remote_parts import MixedModel
    from sm_bt.ros.runtime import RosRuntime

    path = tmp_path / "fleet.yaml"
    path.write_text("fleet:\n  ros__parameters:\n    type: system\n    modes:\n      __DEFAULT__:\n"
                    "        robot1: active\n        lamp: active\nrobot1:\n  ros__parameters:\n    type: remote\n"
                    "    manager: /robot1\n    system: pilot\n    modes: [__DEFAULT__]\n"
                    "lamp:\n  ros__parameters:\n    type: node\n    modes:\n      __DEFAULT__:\n"
                    "        ros__parameters: {on: true}\n")
    expected = "lamp are nodes beside the remote parts robot1: a fleet manager drives remote parts only"
    with pytest.raises(MixedModel, match=expected):
        RosRuntime(load_model(path))
    # In a process of its own, as it runs: it sets up logging and signal handlers for its process.
    done = subprocess.run([sys.executable, "-m", "sm_bt.cli", "manager", str(path)], capture_output=True, text=True,
                          timeout=60)
    assert (done.returncode, done.stdout) == (1, "")
    assert f"sm-bt: error: {path}: {expected}" in done.stderr


def test_the_nodes_backend_refuses_a_fleets_model_and_names_the_one_that_drives_it(ros_context: RosContext) -> None:
    from sm_bt.model import load_model
    from sm_bt.model.remote_parts import MixedModel
    from sm_bt.ros.backend import RosBackend

    fleet = Path(__file__).resolve().parents[2] / "models" / "fleet.yaml"
    with pytest.raises(MixedModel, match=r"its nodes are remote parts: sm_bt.ros.remote_parts.RemoteBackend drives"):
        RosBackend(ros_context.node, load_model(fleet))


def test_a_part_is_judged_unserved_by_the_parts_of_its_own_namespace_only(
        ros_context: RosContext, monkeypatch: pytest.MonkeyPatch) -> None:
    """Robots of a fleet share a domain: another robot's manager, discovered first, does not make
    this robot's part unknown (it waits for the timeout); a sibling of its own namespace does."""
    import sm_bt.ros.client
    from sm_bt.ros.client import ModeClient, UnknownName

    class NeverReady:
        def service_is_ready(self) -> bool:
            return False

    # The discovery's waits scaled down (2 s and 1 s, a timeout of 3.5 s): the same verdicts, sooner.
    monkeypatch.setattr(sm_bt.ros.client, "DISCOVERY_GRACE", 0.2)
    monkeypatch.setattr(sm_bt.ros.client, "DISCOVERY_SETTLED", 0.1)
    client = ModeClient(timeout=0.6, context=ros_context.context)
    try:
        monkeypatch.setattr(client, "served_parts", lambda: ["robot2/pilot", "pilot"])
        assert client._found(NeverReady(), "robot1/pilot") is False  # still discovering: not a typo
        monkeypatch.setattr(client, "served_parts", lambda: ["robot1/pilott", "robot2/pilot"])
        with pytest.raises(UnknownName, match=r"no manager serves the part 'robot1/pilot' \(did you mean "
                                              r"'robot1/pilott'\?\)"):
            client._found(NeverReady(), "robot1/pilot")
        # A manager still being discovered (its parts appearing one by one) is no typo either.
        growing = iter(range(1000))
        monkeypatch.setattr(client, "served_parts", lambda: [f"robot1/part{next(growing)}"])
        assert client._found(NeverReady(), "robot1/pilot") is False
    finally:
        client.close()

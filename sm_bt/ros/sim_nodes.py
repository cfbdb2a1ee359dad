"""Simulated lifecycle nodes as real rclpy nodes: the model's nodes on the ROS graph, with faults on demand.

Each model node becomes an rclpy ``LifecycleNode`` (the lifecycle services and ``transition_event``
of a real managed node) that declares its default mode's parameters with their types, so the ROS
backend, the manager node and tests talk to it exactly as to a Nav2 node. Faults are declared
parameters with the prefix ``sim.``, so any ROS client (another process included) can inject them
with ``set_parameters`` and gets a confirmation:

``sim.transition_delay`` (double, 0.0)
    every transition callback (and ``on_error``) sleeps this long first.
``sim.fail_next`` (string, "")
    ``"<transition>"`` or ``"<transition>:failure"``: the next requested transition with that label
    (configure, cleanup, activate, deactivate, shutdown) returns FAILURE (back to its start state);
    ``"<transition>:error"`` returns ERROR (errorprocessing, then ``on_error`` SUCCESS: unconfigured).
    Used once: the parameter reads ``""`` again afterwards.
``sim.hang_next`` (string, "")
    ``"<transition>"``: the next requested transition with that label enters its transition state
    and never leaves it: its callback waits until the process stops, so the node answers no
    transition meanwhile (nor anything else, with ``--single-threaded``). Used once.
``sim.reject_parameters`` (string, "")
    non-empty: every parameter set that touches a parameter outside ``sim.`` is rejected, with this
    text as the reason. ``sim.*`` sets are always accepted.
``sim.broken`` (bool, false)
    while true, an active node fails by itself within 0.1 s, as the pilot's laser_resender on a
    broken laser: deactivate, ``on_deactivate`` ERROR, errorprocessing, unconfigured. Activating it
    still succeeds (and it fails again shortly after).

``sm-bt sim-nodes MODEL`` (:mod:`sm_bt.cli.sim_nodes`) runs a model's nodes in one process and
prints ``READY /a,/b`` once their services exist; SIGINT or SIGTERM stops it cleanly (exit 0).
"""

from __future__ import annotations

import math
import signal
import threading
import time
import traceback
from collections.abc import Callable, Collection, Sequence
from types import FrameType
from typing import Any

import rclpy
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.context import Context
from rclpy.exceptions import NameValidationException, ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions

from sm_bt.model.errors import Error
from sm_bt.model.types import Model, NodePart, ParamValue
from sm_bt.ros import environment
from sm_bt.ros.names import qualified_name, split_name

PREFIX = "sim."
TRANSITION_DELAY = "sim.transition_delay"
FAIL_NEXT = "sim.fail_next"
HANG_NEXT = "sim.hang_next"
REJECT_PARAMETERS = "sim.reject_parameters"
BROKEN = "sim.broken"

#: The transitions a client can request, by label (rcl's labels; the three shutdowns share one).
REQUESTABLE = ("configure", "cleanup", "activate", "deactivate", "shutdown")
#: The primary states a process can bring its nodes to before it reports READY.
INITIAL_STATES = ("unconfigured", "inactive", "active")
#: How often a broken node checks whether it is active (it must fail within 0.1 s).
BROKEN_CHECK_PERIOD = 0.05

_SUCCESS = TransitionCallbackReturn.SUCCESS
_OUTCOMES = {"failure": TransitionCallbackReturn.FAILURE, "error": TransitionCallbackReturn.ERROR}
#: rclpy raises this (from its C extension) for a transition that is invalid in the current state.
_RCLError: Any = rclpy_implementation.RCLError


def parse_fail_next(text: str) -> tuple[str, TransitionCallbackReturn] | None:
    """The transition label and outcome ``sim.fail_next`` asks for; ``None`` for ``""``.

    ``ValueError`` with the accepted forms for anything else, so that a bad set is rejected.
    """
    if not text:
        return None
    label, _, outcome = text.partition(":")
    if label not in REQUESTABLE or (outcome or "failure") not in _OUTCOMES:
        raise ValueError(
            f"{FAIL_NEXT} must be '' or '<transition>[:failure|:error]' with a transition among "
            f"{', '.join(REQUESTABLE)}; got {text!r}"
        )
    return label, _OUTCOMES[outcome or "failure"]


def _python_value(value: ParamValue) -> Any:
    # rclpy types a parameter from its value; arrays as lists, like rclpy hands them out.
    return list(value) if isinstance(value, tuple) else value


def declare_model_parameters(node: Node, part: NodePart) -> None:
    """Declare the default mode's parameters with their values, statically typed (rclpy's default):
    a set with another type is rejected, as on a real node. An empty array has no element type, so
    it is declared dynamically typed."""
    for name, value in part.modes[part.default_mode].values().items():
        dynamic = isinstance(value, tuple) and not value
        node.declare_parameter(name, _python_value(value), ParameterDescriptor(dynamic_typing=dynamic))


def _rejection(node: Node, parameters: Sequence[Parameter]) -> str | None:
    """Why ``sim.reject_parameters`` refuses this set, or ``None``."""
    reason = str(node.get_parameter(REJECT_PARAMETERS).value)
    if reason and any(not parameter.name.startswith(PREFIX) for parameter in parameters):
        return reason
    return None


class SimulatedNode(LifecycleNode):
    """A model node as an rclpy lifecycle node, with the ``sim.*`` fault parameters (module doc)."""

    def __init__(self, part: NodePart, *, context: Context | None = None, transition_delay: float = 0.0,
                 stop: threading.Event | None = None, namespace: str = "/") -> None:
        inner, name = split_name(part.name, namespace)
        super().__init__(name, namespace=inner, context=context)
        self.part = part
        #: What ends a hung transition (sim.hang_next): the process's stop.
        self._stop = stop if stop is not None else threading.Event()
        # Inherited unannotated rclpy methods, called on the subclass: outside untyped_calls_exclude.
        self._log = self.get_logger()  # type: ignore[no-untyped-call]
        # True while the node runs a deactivate it started itself (sim.broken): not a requested
        # transition, so sim.fail_next does not apply and on_deactivate reports the error.
        self._failing = False
        declare_model_parameters(self, part)
        self.declare_parameter(TRANSITION_DELAY, float(transition_delay), ParameterDescriptor(
            description="seconds every transition callback takes"))
        self.declare_parameter(FAIL_NEXT, "", ParameterDescriptor(
            description="'<transition>[:failure|:error]': the next requested one fails; used once"))
        self.declare_parameter(HANG_NEXT, "", ParameterDescriptor(
            description="'<transition>': the next requested one never ends; used once"))
        self.declare_parameter(REJECT_PARAMETERS, "", ParameterDescriptor(
            description="non-empty: reject sets of non-sim parameters with this reason"))
        self.declare_parameter(BROKEN, False, ParameterDescriptor(
            description="true: fail by itself whenever active (deactivate -> error -> unconfigured)"))
        # Registered after the declarations: the defaults need no checking.
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._parameters_set)
        # Idle unless broken: a timer per node ticking all the time would load the executor.
        self._broken_timer = self.create_timer(BROKEN_CHECK_PERIOD, self._fail_if_broken)
        self._broken_timer.cancel()
        self._guard_change_state()

    @property
    def state(self) -> str:
        """The current lifecycle state's label (``"unconfigured"``, ``"active"``, ``"configuring"``...)."""
        return str(self._state_machine.current_state[1])

    def bring_to(self, state: str) -> None:
        """Run the transitions (locally, not through the service) from unconfigured to ``state``."""
        steps = {"unconfigured": (), "inactive": ("configure",), "active": ("configure", "activate")}[state]
        for label in steps:
            outcome = getattr(self, f"trigger_{label}")()
            if outcome != _SUCCESS:
                raise RuntimeError(f"{self.get_fully_qualified_name()}: {label} returned {outcome} (now {self.state})")

    # -- transition callbacks ------------------------------------------------------------------

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("configure")

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("cleanup")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("activate")

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("deactivate")

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition("shutdown")

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._delay()
        return _SUCCESS  # recovered: rcl moves the node to unconfigured

    def _delay(self) -> None:
        delay = float(self.get_parameter(TRANSITION_DELAY).value)
        if delay > 0.0:
            time.sleep(delay)

    def _transition(self, label: str) -> TransitionCallbackReturn:
        self._delay()
        if self._failing:
            return TransitionCallbackReturn.ERROR
        if str(self.get_parameter(HANG_NEXT).value) == label:
            self.set_parameters([Parameter(HANG_NEXT, value="")])
            self._log.warning(f"{HANG_NEXT}: {label} hangs until the process stops")
            self._stop.wait()
            return TransitionCallbackReturn.ERROR
        planned = parse_fail_next(str(self.get_parameter(FAIL_NEXT).value))
        if planned is None or planned[0] != label:
            return _SUCCESS
        # Consumed through the parameter itself, so that clients read "" and see a parameter event.
        self.set_parameters([Parameter(FAIL_NEXT, value="")])
        self._log.info(f"{FAIL_NEXT}: {label} returns {planned[1].to_label()}")
        return planned[1]

    # -- faults -----------------------------------------------------------------------------------

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        reason = _rejection(self, parameters)
        if reason is not None:
            return SetParametersResult(successful=False, reason=reason)
        for parameter in parameters:
            if parameter.name == FAIL_NEXT:
                try:
                    parse_fail_next(str(parameter.value))
                except ValueError as error:
                    return SetParametersResult(successful=False, reason=str(error))
            elif parameter.name == HANG_NEXT and parameter.value not in ("", *REQUESTABLE):
                reason = f"{HANG_NEXT} must be '' or one of {', '.join(REQUESTABLE)}; got {parameter.value!r}"
                return SetParametersResult(successful=False, reason=reason)
            elif parameter.name == TRANSITION_DELAY and not 0.0 <= float(parameter.value) < math.inf:
                return SetParametersResult(
                    successful=False, reason=f"{TRANSITION_DELAY} must be a finite number of seconds >= 0")
        return SetParametersResult(successful=True)

    def _parameters_set(self, parameters: list[Parameter]) -> None:
        for parameter in parameters:
            if parameter.name == BROKEN:
                # reset() also wakes the executor's wait, so the first check comes within a period.
                if parameter.value:
                    self._broken_timer.reset()
                else:
                    self._broken_timer.cancel()

    def _fail_if_broken(self) -> None:
        # A timer of the node, never a service or parameter callback: the failure is the node's own
        # transition, published on transition_event like any other, after the set was answered.
        if not self.get_parameter(BROKEN).value or self.state != "active":
            return
        self._log.warning(f"{BROKEN}: failing by itself (deactivate -> error -> unconfigured)")
        self._failing = True
        try:
            self.trigger_deactivate()  # type: ignore[no-untyped-call]
        except _RCLError as error:  # the state changed under us; the next tick checks again
            self._log.warning(f"{BROKEN}: could not deactivate: {error}")
        finally:
            self._failing = False

    def _guard_change_state(self) -> None:
        # rclpy 7.1.6 raises RCLError out of the executor when change_state names a transition id
        # that is invalid in the current state, and the whole process stops serving. rclcpp answers
        # success=false instead; so does this wrapper.
        service = self._service_change_state
        answer = service.callback

        def guarded(request: Any, response: Any) -> Any:
            try:
                return answer(request, response)
            except _RCLError as error:
                self._log.warning(
                    f"refused transition id {request.transition.id} in state {self.state}: {error}")
                response.success = False
                return response

        service.callback = guarded


class SimulatedParameterNode(Node):
    """A model node as a plain rclpy node (no lifecycle services): its parameters and
    ``sim.reject_parameters``, for tests of nodes that are not managed."""

    def __init__(self, part: NodePart, *, context: Context | None = None, namespace: str = "/") -> None:
        inner, name = split_name(part.name, namespace)
        super().__init__(name, namespace=inner, context=context)
        self.part = part
        declare_model_parameters(self, part)
        self.declare_parameter(REJECT_PARAMETERS, "", ParameterDescriptor(
            description="non-empty: reject sets of non-sim parameters with this reason"))
        self.add_on_set_parameters_callback(self._check_parameters)

    def _check_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        reason = _rejection(self, parameters)
        return SetParametersResult(successful=reason is None, reason=reason or "")


def select_nodes(model: Model, only: Collection[str] | None = None,
                 parameters_only: Collection[str] = ()) -> tuple[list[NodePart], list[NodePart]]:
    """The lifecycle parts and the plain parts to run, in model order.

    ``only`` (default: every node) and ``parameters_only`` name model nodes; a name in
    ``parameters_only`` runs as a plain node whether or not it is also in ``only``.
    ``ValueError`` listing the model's nodes for a name that is not one of them.
    """
    nodes = {node.name.strip("/"): node for node in model.nodes}
    wanted = [name.strip("/") for name in (*(only or ()), *parameters_only)]
    unknown = [name for name in wanted if name not in nodes]
    if unknown:
        raise ValueError(f"not a node of {model.path}: {', '.join(unknown)} (nodes: {', '.join(nodes)})")
    plain = {name.strip("/") for name in parameters_only}
    chosen = set(nodes) if only is None else {name.strip("/") for name in (*only, *parameters_only)}
    return ([node for name, node in nodes.items() if name in chosen and name not in plain],
            [node for name, node in nodes.items() if name in plain])


class RefusedName(Error, ValueError):
    """A part or parameter name of the model that ROS refuses (rclpy's message)."""


def print_ready(names: Sequence[str]) -> None:
    """The line a parent process waits for: ``READY /a,/b``."""
    print("READY " + ",".join(names), flush=True)


def run_nodes(
    model: Model,
    names: Collection[str] | None = None,
    *,
    initial_state: str = "unconfigured",
    parameters_only: Collection[str] = (),
    transition_delay: float = 0.0,
    single_threaded: bool = False,
    ready: Callable[[list[str]], None] | None = print_ready,
    stop: threading.Event | None = None,
    namespace: str = "/",
) -> None:
    """Run the model's nodes (``names``, default all) in this process until ``stop`` is set.

    The lifecycle nodes are first brought to ``initial_state``; ``ready`` then gets their fully
    qualified names (lifecycle first, then plain); ``transition_delay`` is every lifecycle node's
    first ``sim.transition_delay``; ``namespace`` puts every node under it (``/robot1/amcl``).
    ``single_threaded``: one executor thread for all the nodes, as in
    rclcpp's component container, so that a node in a long transition holds up the others (by
    default each node has a thread). Without ``stop``, SIGINT and SIGTERM end the
    run (this needs the main thread). Shutdown order: executor, its thread, the nodes, the context.
    ``ValueError`` for unknown names or states; :class:`RefusedName` (a ``ValueError``) for a part
    or parameter name that ROS refuses.
    """
    if initial_state not in INITIAL_STATES:
        raise ValueError(f"initial state must be one of {', '.join(INITIAL_STATES)}, not {initial_state!r}")
    lifecycle_parts, plain_parts = select_nodes(model, names, parameters_only)
    if stop is None:
        stop = threading.Event()
        restore = _stop_on_signals(stop)
    else:
        restore = _nothing
    environment.prepare(local_only=False)  # stand-ins for a robot's nodes: the user's discovery settings
    context = Context()
    # No rclpy signal handlers: ours only set `stop`, and the shutdown order stays ours.
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    nodes: list[SimulatedNode | SimulatedParameterNode] = []
    executor: MultiThreadedExecutor | None = None
    spinner: threading.Thread | None = None
    failure: list[BaseException] = []
    try:
        try:
            lifecycle = [SimulatedNode(part, context=context, transition_delay=transition_delay, stop=stop,
                                       namespace=namespace) for part in lifecycle_parts]
            nodes.extend(lifecycle)
            nodes.extend(SimulatedParameterNode(part, context=context, namespace=namespace) for part in plain_parts)
        except (NameValidationException, ParameterException) as error:
            raise RefusedName(str(error)) from None
        for managed in lifecycle:
            managed.bring_to(initial_state)
        # One thread per node: each node's callbacks are mutually exclusive (its default group),
        # so a node sleeping in sim.transition_delay never holds up another node. With one thread,
        # it holds up every node of the process.
        executor = MultiThreadedExecutor(num_threads=1 if single_threaded else len(nodes) + 1, context=context)
        for node in nodes:
            executor.add_node(node)
        spinner = threading.Thread(target=_spin, args=(executor, stop, failure), name="sim-nodes", daemon=True)
        spinner.start()
        if ready is not None:
            ready([qualified_name(node.part.name, namespace) for node in nodes])
        while not stop.wait(0.2):  # a timeout, so that signal handlers run promptly
            pass
    finally:
        restore()
        if executor is not None:
            executor.shutdown(timeout_sec=2.0)
        if spinner is not None:
            spinner.join(timeout=3.0)
        for node in nodes:
            node.destroy_node()  # type: ignore[no-untyped-call]
        context.try_shutdown()
    if failure:
        raise RuntimeError("the executor stopped with an error") from failure[0]


def _spin(executor: MultiThreadedExecutor, stop: threading.Event, failure: list[BaseException]) -> None:
    try:
        executor.spin()
    except ExternalShutdownException:
        pass
    except BaseException as error:  # ends the run instead of leaving a process that no longer serves
        traceback.print_exc()
        failure.append(error)
    finally:
        stop.set()


def _nothing() -> None:
    pass


def _stop_on_signals(stop: threading.Event) -> Callable[[], None]:
    """Make SIGINT and SIGTERM set ``stop``; returns the function restoring the previous handlers."""

    def handler(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {number: signal.signal(number, handler) for number in (signal.SIGINT, signal.SIGTERM)}

    def restore() -> None:
        for number, old in previous.items():
            signal.signal(number, old)

    return restore

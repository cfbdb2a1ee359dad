"""BehaviorTree.CPP's control and decorator nodes that py_trees lacks, with their documented
semantics, so that trees written for BehaviorTree.CPP and Nav2 load as they are.

Controls: ``RecoveryNode``, ``PipelineSequence``, ``RoundRobin`` (Nav2), ``IfThenElse``,
``WhileDoElse`` (BehaviorTree.CPP). Decorators: ``RateController`` (Nav2), ``Delay``,
``RetryUntilSuccessful``, ``KeepRunningUntilFailure``, ``ForceSuccess``, ``ForceFailure``
(BehaviorTree.CPP; ``Inverter`` is py_trees' own). Each is a py_trees ports class registered
under its BehaviorTree.CPP tag. Where BehaviorTree.CPP *halts* a child, these stop it
(``INVALID``). Time is the tree's clock, ``tree.setup(clock=...)`` (an object with ``now()``: a
run on simulated nodes passes its virtual clock), else ``time.monotonic``.
"""

from __future__ import annotations

import time
from collections.abc import Generator, Iterable, Iterator
from typing import Any

import py_trees
from py_trees.behaviour import Behaviour
from py_trees.common import Status
from py_trees.ports import PortInformation, PortsMixin

#: What ticks a node's children: yields what they yield, returns the node's status.
Work = Generator[Behaviour, None, Status]


def _number(name: str, what: str, value: str | float, kind: type[int] | type[float]) -> Any:
    """``value`` (an XML attribute's text, or a number) as ``kind``; ``ValueError`` naming it."""
    try:
        return kind(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: {what} must be {'a whole number' if kind is int else 'a number'}, "
                         f"not {value!r}") from None


class _Cpp(PortsMixin, register=False):
    """A node of BehaviorTree.CPP's: its attributes are constructor arguments, not ports."""

    INPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012 (py_trees' read-only declaration)
    OUTPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        self._subtree_namespace = subtree_namespace


def _halt(children: Iterable[Behaviour]) -> None:
    for child in children:
        if child.status != Status.INVALID:
            child.stop(Status.INVALID)


class _Control(_Cpp, py_trees.composites.Composite, register=False):
    """A composite whose :meth:`work` ticks its children and returns its status."""

    def __init__(self, name: str, children: list[Behaviour] | None = None, **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            _halt(self.children)
            self.initialise()
        status = yield from self.work()
        if status == Status.RUNNING:
            self.status = status
        else:
            _halt(self.children)  # BehaviorTree.CPP halts every child when a control ends
            self.stop(status)
        yield self

    def work(self) -> Work:  # a generator that returns the status
        raise NotImplementedError
        yield self

    def _tick(self, child: Behaviour) -> Work:
        """Tick ``child`` (yielding what it yields) and return its status."""
        self.current_child = child
        yield from child.tick()
        return child.status


class RecoveryNode(_Control, tag="RecoveryNode"):
    """Nav2's: two children, the work and the recovery. The work's SUCCESS is SUCCESS; on its
    FAILURE the recovery runs, and its SUCCESS tries the work again (``number_of_retries`` times
    at most, then FAILURE); the recovery's FAILURE is FAILURE. RUNNING while either runs."""

    def __init__(self, name: str, number_of_retries: int = 1, children: list[Behaviour] | None = None,
                 **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)
        if len(self.children) != 2:
            raise ValueError(f"{name}: RecoveryNode takes two children (the work, the recovery), not "
                             f"{len(self.children)}")
        number_of_retries = _number(name, "number_of_retries", number_of_retries, int)
        if number_of_retries < 0:
            raise ValueError(f"{name}: number_of_retries must be 0 or more, not {number_of_retries}")
        self.number_of_retries = number_of_retries
        self.retries = 0
        self.recovering = False

    def initialise(self) -> None:
        self.retries = 0
        self.recovering = False

    def work(self) -> Work:
        work, recovery = self.children
        while True:
            if not self.recovering:
                status = yield from self._tick(work)
                if status != Status.FAILURE:
                    return status
                if self.retries >= self.number_of_retries:
                    return Status.FAILURE
                self.recovering = True
            status = yield from self._tick(recovery)
            if status != Status.SUCCESS:
                return status
            self.recovering = False
            self.retries += 1
            _halt([work])


class PipelineSequence(_Control, tag="PipelineSequence"):
    """Nav2's: ticks the children in order on every tick, each one up to the furthest reached so
    far: a child before it that is RUNNING keeps running while the next ones are ticked; the
    furthest child's RUNNING is RUNNING. Any FAILURE is FAILURE; the last child's SUCCESS is SUCCESS."""

    def __init__(self, name: str, children: list[Behaviour] | None = None, **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)
        self.reached = 0

    def initialise(self) -> None:
        self.reached = 0

    def work(self) -> Work:
        for index, child in enumerate(self.children):
            status = yield from self._tick(child)
            if status == Status.FAILURE:
                return status
            if status == Status.RUNNING and index >= self.reached:
                self.reached = index
                return status
        return Status.SUCCESS


class RoundRobin(_Control, tag="RoundRobin"):
    """Nav2's: ticks one child at a time, starting after the last one that ended. Its SUCCESS is
    SUCCESS (and the next tick starts with the one after it); on FAILURE the next child is ticked
    in the same tick; FAILURE once every child failed in turn. RUNNING while a child runs."""

    def __init__(self, name: str, children: list[Behaviour] | None = None, **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)
        self.next_index = 0
        self.failed = 0  # children failed in turn since the last success (across ticks, as Nav2's)

    def initialise(self) -> None:
        self.failed = 0

    def work(self) -> Work:
        while self.failed < len(self.children):
            index = self.next_index
            status = yield from self._tick(self.children[index])
            if status == Status.RUNNING:
                return status
            self.next_index = (index + 1) % len(self.children)
            if status == Status.SUCCESS:
                return status
            self.failed += 1
        return Status.FAILURE


class IfThenElse(_Control, tag="IfThenElse"):
    """BehaviorTree.CPP's: the first child is the condition, then the "then" and (optional) "else"
    children. The condition's SUCCESS runs "then", its FAILURE "else" (FAILURE without one); the
    branch chosen runs until it ends (the condition is not asked again meanwhile)."""

    def __init__(self, name: str, children: list[Behaviour] | None = None, **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)
        if len(self.children) not in (2, 3):
            raise ValueError(f"{name}: IfThenElse takes 2 or 3 children (if, then[, else]), not {len(self.children)}")
        self.branch: Behaviour | None = None

    def initialise(self) -> None:
        self.branch = None

    def work(self) -> Work:
        if self.branch is None:
            condition = yield from self._tick(self.children[0])
            if condition == Status.RUNNING:
                return condition
            if condition == Status.SUCCESS:
                self.branch = self.children[1]
            elif len(self.children) == 3:
                self.branch = self.children[2]
            else:
                return Status.FAILURE
        return (yield from self._tick(self.branch))


class WhileDoElse(_Control, tag="WhileDoElse"):
    """BehaviorTree.CPP's: like ``IfThenElse`` but reactive: the condition is asked on every tick,
    and a change of its answer stops the branch that was running for the other one."""

    def __init__(self, name: str, children: list[Behaviour] | None = None, **kwargs: Any) -> None:
        super().__init__(name, children=children, **kwargs)
        if len(self.children) not in (2, 3):
            raise ValueError(f"{name}: WhileDoElse takes 2 or 3 children (while, do[, else]), not "
                             f"{len(self.children)}")

    def work(self) -> Work:
        condition = yield from self._tick(self.children[0])
        if condition == Status.RUNNING:
            return condition
        chosen = 1 if condition == Status.SUCCESS else 2
        _halt(child for index, child in enumerate(self.children) if index not in (0, chosen))
        if chosen >= len(self.children):
            return Status.FAILURE
        return (yield from self._tick(self.children[chosen]))


class _Wrapper(_Cpp, py_trees.decorators.Decorator, register=False):
    """A decorator whose :meth:`work` decides when to tick the child and what to return."""

    def __init__(self, name: str, child: Behaviour, **kwargs: Any) -> None:
        super().__init__(name=name, child=child, **kwargs)

    def tick(self) -> Iterator[Behaviour]:
        if self.status != Status.RUNNING:
            self.initialise()
        status = yield from self.work()
        if status == Status.RUNNING:
            self.status = status
        else:
            _halt([self.decorated])
            self.stop(status)
        yield self

    def work(self) -> Work:
        raise NotImplementedError
        yield self

    def _tick_child(self) -> Work:
        yield from self.decorated.tick()
        return self.decorated.status

    def update(self) -> Status:  # Decorator's abstract method; tick() does the work
        return self.status


class ForceSuccess(_Wrapper, tag="ForceSuccess"):
    """The child's RUNNING is RUNNING; its end, whichever, SUCCESS."""

    def work(self) -> Work:
        status = yield from self._tick_child()
        return Status.RUNNING if status == Status.RUNNING else Status.SUCCESS


class ForceFailure(_Wrapper, tag="ForceFailure"):
    """The child's RUNNING is RUNNING; its end, whichever, FAILURE."""

    def work(self) -> Work:
        status = yield from self._tick_child()
        return Status.RUNNING if status == Status.RUNNING else Status.FAILURE


class KeepRunningUntilFailure(_Wrapper, tag="KeepRunningUntilFailure"):
    """RUNNING while the child runs or succeeds (a success starts it again on the next tick);
    the child's FAILURE is FAILURE."""

    def work(self) -> Work:
        status = yield from self._tick_child()
        return Status.FAILURE if status == Status.FAILURE else Status.RUNNING


class RetryUntilSuccessful(_Wrapper, tag="RetryUntilSuccessful"):
    """The child's SUCCESS is SUCCESS; on its FAILURE it is ticked again, in the same tick, up to
    ``num_attempts`` times in all (FAILURE then; -1: for ever)."""

    def __init__(self, name: str, child: Behaviour, num_attempts: int = 1, **kwargs: Any) -> None:
        super().__init__(name, child, **kwargs)
        num_attempts = _number(name, "num_attempts", num_attempts, int)
        if num_attempts == 0 or num_attempts < -1:
            raise ValueError(f"{name}: num_attempts must be 1 or more, or -1 (for ever), not {num_attempts}")
        self.num_attempts = num_attempts
        self.attempts = 0

    def initialise(self) -> None:
        self.attempts = 0

    def work(self) -> Work:
        while True:
            status = yield from self._tick_child()
            if status != Status.FAILURE:
                return status
            self.attempts += 1
            if self.num_attempts != -1 and self.attempts >= self.num_attempts:
                return Status.FAILURE
            _halt([self.decorated])


class _Timed(_Wrapper, register=False):
    """A decorator that measures time on the tree's clock (``setup(clock=...)``)."""

    def __init__(self, name: str, child: Behaviour, **kwargs: Any) -> None:
        super().__init__(name, child, **kwargs)
        self._clock: Any = None

    def setup(self, **kwargs: Any) -> None:
        super().setup(**kwargs)
        self._clock = kwargs.get("clock", self._clock)

    def now(self) -> float:
        return float(self._clock.now()) if self._clock is not None else time.monotonic()


class Delay(_Timed, tag="Delay"):
    """RUNNING for ``delay_msec`` milliseconds without ticking the child, then the child's status."""

    def __init__(self, name: str, child: Behaviour, delay_msec: float = 0, **kwargs: Any) -> None:
        super().__init__(name, child, **kwargs)
        delay_msec = _number(name, "delay_msec", delay_msec, float)
        if delay_msec < 0:
            raise ValueError(f"{name}: delay_msec must be 0 or more, not {delay_msec}")
        self.delay = delay_msec / 1000.0
        self.started = 0.0

    def initialise(self) -> None:
        self.started = self.now()

    def work(self) -> Work:
        waited = self.now() - self.started
        if waited < self.delay:
            self.feedback_message = f"waiting {self.delay - waited:.1f} s"
            return Status.RUNNING
        self.feedback_message = ""
        return (yield from self._tick_child())


class RateController(_Timed, tag="RateController"):
    """Nav2's: ticks the child at most ``hz`` times a second: on the first tick, while the child
    runs, and once a period passed since it last succeeded; RUNNING in between (also when ticked
    on after a success: the period runs from that success). The child's SUCCESS is SUCCESS, its
    FAILURE FAILURE; a halt starts it afresh."""

    def __init__(self, name: str, child: Behaviour, hz: float = 10.0, **kwargs: Any) -> None:
        super().__init__(name, child, **kwargs)
        hz = _number(name, "hz", hz, float)
        if not hz > 0:
            raise ValueError(f"{name}: hz must be more than 0, not {hz}")
        self.period = 1.0 / hz
        self.started = 0.0
        self.first = True

    def initialise(self) -> None:
        if self.status == Status.SUCCESS:
            return  # ticked on after its success (as in a PipelineSequence): the period goes on
        self.started = self.now()
        self.first = True

    def work(self) -> Work:
        now = self.now()
        if self.first or self.decorated.status == Status.RUNNING or now - self.started >= self.period:
            self.first = False
            status = yield from self._tick_child()
            if status == Status.SUCCESS:
                self.started = now
            return status
        return Status.RUNNING


#: Every node this module adds, by tag.
NODES = {cls.__name__: cls for cls in (RecoveryNode, PipelineSequence, RoundRobin, IfThenElse, WhileDoElse,
                                       ForceSuccess, ForceFailure, KeepRunningUntilFailure, RetryUntilSuccessful,
                                       Delay, RateController)}

__all__ = [*NODES, "NODES"]

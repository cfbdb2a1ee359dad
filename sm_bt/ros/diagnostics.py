"""The manager's view on ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``), the ROS convention
that ``rqt_robot_monitor`` and ``diagnostic_aggregator`` read.

One ``DiagnosticStatus`` per part of the model, named ``"{manager node}: {part}"`` with the part as
``hardware_id``:

* **OK**: the part is what it was asked to be (or, with no target, its state is known);
* **WARN**: on its way (a request in flight, a divergence within its grace period), its last
  request was refused, or its link is slow (answers arrive, late);
* **ERROR**: unreachable, diverging beyond the grace period, its last request failed and it is
  not at its target, or recovery gave up on it;
* **STALE**: a node not seen on the ROS graph yet.

``values`` carry ``target``, ``actual``, ``divergence``, the last request (``last_request``,
``last_request_outcome``: running/succeeded/failed/refused, ``last_request_reason``,
``last_request_by``), who holds it (``held_by``: ``metacontroller (priority 60, until 12.3 s)``,
empty when nobody) and for nodes ``reachable``, ``last_return`` (how it came back the last time
it was out of reach: ``unconfigured (back after 4.2 s; was active.f_normal)``), ``round_trip_ms`` and
``liveness_window_s``.

A part's status goes out within ``GATHER`` (0.1 s) of a change (the changed parts only, one message
per burst: aggregators keep the last status per name; a request's failure at once), and every part's
every ``period`` seconds, as ``diagnostic_updater`` does, so that a late joiner and the aggregators'
staleness checks see it. While nobody subscribes, nothing is built (a full message of 20 nodes is
a thousand small Python objects, made under the manager's lock).

A model of more than ``limit`` (1,000) parts is published in pages (:class:`Paging`): each
message carries at most ``limit`` statuses. Every period's message has the parts at the top of the
hierarchy, every part that diverges, and the next page of the others in turn, so that each part
is published at least once per :attr:`Paging.cycle` periods; a status named ``"{manager node}:
summary"`` (no ``hardware_id``) counts the parts and the divergences. A burst of changes larger than
a message goes out over several gatherings, errors and the top of the hierarchy first.
"""

from __future__ import annotations

import heapq
import logging
import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from sm_bt.engine.clock import Clock, TimerHandle
from sm_bt.engine.events import Divergence, Event, EventKind, Subscription
from sm_bt.engine.manager import ModeManager
from sm_bt.engine.requests import Request
from sm_bt.model.hierarchy import parts_below, top_down
from sm_bt.model.types import NodePart
from sm_bt.monitor_rows import parts_phrase
from sm_bt.ros import removable

log = logging.getLogger("sm_bt.ros.diagnostics")

OK, WARN, ERROR, STALE = 0, 1, 2, 3
LEVEL_NAMES = {OK: "OK", WARN: "WARN", ERROR: "ERROR", STALE: "STALE"}
#: Every part's status is published this often (seconds), besides every change.
PERIOD = 1.0
#: Changes are gathered this long before they go out: one message for a change's burst of events,
#: built after the change rather than in the middle of it (its threads also carry the answers).
GATHER = 0.1
#: The most statuses in one message: a larger model is published in pages.
LIMIT = 1000


class Paging:
    """Which parts each message carries, for a model of ``parts`` (``children``: each system's
    parts) when there are more than ``limit``: see the module."""

    def __init__(self, parts: Iterable[str], children: Mapping[str, tuple[str, ...]], limit: int = LIMIT) -> None:
        if limit < 2:
            raise ValueError(f"a page holds at least two statuses, not {limit}")
        order = top_down(parts, children)
        self.limit = limit
        self.paged = len(order) > limit
        self._rank = {part: index for index, part in enumerate(order)}
        # A quarter for the top of the hierarchy, up to half for divergences, the rest for a page.
        top = limit // 4 if self.paged else len(order)
        self._top, self._others = order[:top], order[top:]
        self._most_diverging = limit // 2
        self._cursor = 0

    @property
    def cycle(self) -> int:
        """Periods within which every part is published at least once (with divergences filling
        their share of every message)."""
        if not self.paged:
            return 1
        page = self.limit - len(self._top) - self._most_diverging
        return -(-len(self._others) // page)

    def periodic(self, diverging: Iterable[str]) -> list[str]:
        """The parts of the next periodic message (``diverging``: the parts that diverge now)."""
        if not self.paged:
            return list(self._top)
        top = set(self._top)
        extra = heapq.nsmallest(self._most_diverging, (part for part in set(diverging) if part not in top),
                                key=self._rank.__getitem__)
        chosen = top.union(extra)
        others = self._others
        page: list[str] = []
        for _ in range(len(others)):
            if len(chosen) + len(page) >= self.limit:
                break
            part = others[self._cursor]
            self._cursor = (self._cursor + 1) % len(others)
            if part not in chosen:
                page.append(part)
        return sorted((*chosen, *page), key=self._rank.__getitem__)

    def burst(self, changed: set[str], urgent: set[str]) -> tuple[list[str], set[str]]:
        """The changed parts to publish now, ``urgent`` ones first, and those left for the next gathering."""
        rank = self._rank
        if len(changed) <= self.limit:
            return sorted(changed, key=rank.__getitem__), set()
        now = heapq.nsmallest(self.limit, changed, key=lambda part: (part not in urgent, rank[part]))
        return sorted(now, key=rank.__getitem__), changed.difference(now)


@dataclass(frozen=True)
class PartDiagnostic:
    """What one part's ``DiagnosticStatus`` says."""

    part: str
    level: int
    message: str
    values: tuple[tuple[str, str], ...]

    def value(self, key: str) -> str:
        return dict(self.values)[key]


def part_diagnostic(manager: ModeManager, part: str, last: Request | None, link: Any = None) -> PartDiagnostic:
    """The status of ``part`` now (call with the manager's lock held); ``last``: its last request,
    ``link``: for a node, how it answers (:class:`sm_bt.ros.backend.Link`), if known."""
    status = manager.status(part)
    actual, target, divergence = status.actual, status.target, status.divergence
    outcome = last.outcome if last is not None else ""
    values: list[tuple[str, str]] = [
        ("target", str(target) if target is not None else ""),
        ("actual", str(actual)),
        ("divergence", (f"{divergence.cause.value}" + (f": {divergence.reason}" if divergence.reason else ""))
         if divergence is not None else ""),
        ("last_request", f"#{last.id} {last.description}" if last is not None else ""),
        ("last_request_outcome", outcome),
        ("last_request_reason", last.reason if last is not None else ""),
        ("last_request_by", last.requester if last is not None else ""),
        ("held_by", status.held_by),
    ]
    if status.reachable is not None:
        values.append(("reachable", "true" if status.reachable else "false"))
        back = status.last_return
        values.append(("last_return", back.describe() if back is not None else ""))
        if link is not None:
            values.append(("round_trip_ms", f"{link.rtt * 1000:.1f}" if link.rtt is not None else ""))
            values.append(("liveness_window_s", f"{link.window:.2f}"))
    at_target = actual.known if target is None else actual.is_(target)

    level, message = OK, str(actual)
    if status.reachable is False:
        if status.gone:
            level, message = ERROR, f"unreachable: {status.gone}"
        else:
            level, message = STALE, "not found on the ROS graph yet"
    elif status.gave_up:
        level, message = ERROR, f"recovery gave up: {divergence.reason if divergence else actual}"
    elif divergence is not None and divergence.is_error:
        level, message = ERROR, f"target {divergence.target}, actual {actual}" + (
            f" ({divergence.reason})" if divergence.reason else "")
    elif outcome == "failed" and not at_target:
        level, message = ERROR, f"request #{last.id} failed: {last.reason}"  # type: ignore[union-attr]
    elif outcome == "running":
        level, message = WARN, f"request #{last.id} {last.description}: {last.feedback}"  # type: ignore[union-attr]
    elif divergence is not None:
        level, message = WARN, f"target {divergence.target}, actual {actual} ({divergence.cause.value})"
    elif outcome == "refused":
        level, message = WARN, f"{actual}; request #{last.id} refused: {last.reason}"  # type: ignore[union-attr]
    elif not actual.known:
        level, message = WARN, f"unknown: {actual.reason}" if actual.reason else "unknown"
    if level == OK and link is not None and link.slow:
        level, message = WARN, (f"{actual}; slow link: answers in {link.rtt * 1000:.0f} ms, silence for "
                                f"{link.window:.1f} s means unreachable")
    return PartDiagnostic(part, level, message, tuple(values))


class DiagnosticsPublisher:
    """Publish ``manager``'s parts on ``/diagnostics`` from ``node``, on change and every ``period``
    seconds (timed by ``clock``); ``link(node)`` says how a node answers, if the backend knows."""

    def __init__(self, node: Any, manager: ModeManager, clock: Clock, *, period: float = PERIOD,
                 link: Callable[[str], Any] | None = None, topic: str = "/diagnostics", limit: int = LIMIT) -> None:
        from diagnostic_msgs.msg import DiagnosticArray

        self._node = node
        self._manager = manager
        self._clock = clock
        self._period = period
        self._link = link
        self._name = node.get_name()
        self._publisher = removable.publisher(node, DiagnosticArray, topic, 10)
        self._lock = threading.Lock()
        self._last: dict[str, Request] = {}
        #: Requests that ended badly and whose status has not gone out yet: one the next request of the
        #: part replaced before the gathering is published with it all the same (a waiting client's news).
        self._unpublished: dict[str, Request] = {}
        self._dirty: set[str] = set()
        self._urgent: set[str] = set()  # of the dirty parts, those to publish first (failures)
        model = manager.model
        self._children = {system.name: system.parts for system in model.systems}
        self._paging = Paging(model.parts, self._children, limit)
        self._flush: TimerHandle | None = None
        self._closed = False
        with manager.lock:
            self._subscription: Subscription | None = manager.subscribe(self._on_event)
        self._timer: TimerHandle | None = clock.call_later(0.0, self._publish_all)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            for timer in (self._timer, self._flush):
                if timer is not None:
                    timer.cancel()
        if self._subscription is not None:
            self._subscription.cancel()
            self._subscription = None
        self._node.destroy_publisher(self._publisher)

    def requested(self, part: str, request: Request) -> None:
        """A request made outside the engine's events (one refused for a name the model lacks)."""
        self._note(part, request)

    # -- events (in the manager's lock) --------------------------------------------------------------

    def _on_event(self, event: Event) -> None:
        if event.kind is EventKind.REQUEST and event.request is not None:
            self._note(event.request.part, event.request)
        elif event.kind in (EventKind.ACTUAL, EventKind.TARGET, EventKind.DIVERGENCE, EventKind.FAILED):
            self._changed(event.part)
        elif event.kind is EventKind.HOLD:  # held_by changes on the part and every part below it
            for name in (event.part, *parts_below(event.part, self._children)):
                self._changed(name)

    def _note(self, part: str, request: Request) -> None:
        failed = request.done and not request.succeeded
        with self._lock:
            self._last[part] = request
            if failed:
                self._unpublished[part] = request
        # A failure is news at once; a start or a success can wait for the burst around it (a caller
        # may start the next change right away: publishing then would hold its answers back).
        self._changed(part, now=failed)

    def _changed(self, part: str, now: bool = False) -> None:
        with self._lock:
            # Nobody reads it: nothing to gather (a reader that comes gets every part within `period`).
            # Asked once per gathering, not per event (a change of 100,000 parts is 300,000 events).
            if self._closed or part not in self._manager.model.parts or (
                    self._flush is None and not self._publisher.get_subscription_count()):
                return
            self._dirty.add(part)
            if now:
                self._urgent.add(part)
            if now and self._flush is not None:
                self._flush.cancel()
                self._flush = None
            if self._flush is None:  # one publication for a burst of events
                self._flush = self._clock.call_later(0.0 if now else GATHER, self._publish_dirty)

    # -- publishing (clock thread) ---------------------------------------------------------------------

    def _publish_dirty(self) -> None:
        with self._lock:
            parts, self._dirty = self._paging.burst(self._dirty, self._urgent)
            self._urgent.intersection_update(self._dirty)
            # What did not fit goes with the next gathering.
            self._flush = self._clock.call_later(GATHER, self._publish_dirty) if self._dirty else None
        self._publish(parts)

    def _publish_all(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._timer = self._clock.call_later(self._period, self._publish_all)
        if not self._paging.paged:
            self._publish(list(self._manager.model.parts))
        elif self._publisher.get_subscription_count():
            divergences = self._manager.divergences()
            self._publish(self._paging.periodic(d.part for d in divergences), self._summary(divergences))

    def _summary(self, divergences: list[Divergence]) -> PartDiagnostic:
        """The status that counts the parts of a paged model and their divergences."""
        model, errors = self._manager.model, sum(d.is_error for d in divergences)
        systems = len(self._children)
        level = ERROR if errors else WARN if divergences else OK
        every = self._paging.cycle * self._period
        message = (f"{parts_phrase(len(model.parts), systems)}: {len(divergences):,} diverge, {errors:,} beyond "
                   f"their grace period; {self._paging.limit:,} statuses a message, each part at least every "
                   f"{every:g} s")
        return PartDiagnostic("", level, message, (("parts", str(len(model.parts))),
                                                  ("diverging", str(len(divergences))), ("errors", str(errors)),
                                                  ("every_part_within_s", f"{every:g}")))

    def statuses(self, parts: list[str]) -> list[PartDiagnostic]:
        """Each part's status now; before it, that of a failure a later request replaced unpublished."""
        manager = self._manager
        with manager.lock:
            with self._lock:
                last = {part: self._last.get(part) for part in parts}
                missed = {part: failure for part in parts
                          if (failure := self._unpublished.pop(part, None)) is not None and failure is not last[part]}
            found = []
            for part in parts:
                link = self._link_of(part)
                if part in missed:
                    found.append(part_diagnostic(manager, part, missed[part], link))
                found.append(part_diagnostic(manager, part, last[part], link))
            return found

    def _link_of(self, part: str) -> Any:
        if self._link is None or not isinstance(self._manager.model.parts[part], NodePart):
            return None
        try:
            return self._link(part)
        except KeyError:
            return None

    def _publish(self, parts: list[str], summary: PartDiagnostic | None = None) -> None:
        from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

        if not parts or self._closed or not self._publisher.get_subscription_count():
            with self._lock:  # nobody reads it (a volatile topic): a reader that comes gets all within `period`,
                for part in parts:  # as they are then
                    self._unpublished.pop(part, None)
            return
        message = DiagnosticArray()
        message.header.stamp = self._node.get_clock().now().to_msg()
        message.status = [
            DiagnosticStatus(level=bytes([status.level]), name=f"{self._name}: {status.part or 'summary'}",
                             message=status.message, hardware_id=status.part,
                             values=[KeyValue(key=k, value=v) for k, v in status.values])
            for status in ([summary] if summary is not None else []) + self.statuses(parts)]
        try:
            self._publisher.publish(message)
        except Exception:  # the node is going away (shutdown): nothing to tell anyone any more
            log.debug("publishing diagnostics failed", exc_info=True)


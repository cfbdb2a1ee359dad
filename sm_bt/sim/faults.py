"""The faults armed in a simulation, and the delays set per node: they belong to the simulation,
not to a node's process, so they survive a restart until used or cleared."""

from __future__ import annotations

from dataclasses import dataclass

from sm_bt.engine.lifecycle import Outcome, Transition


@dataclass(frozen=True)
class Failure:
    """What a transition's callback returns, and then ``on_error`` when it returned ERROR."""

    outcome: Outcome
    on_error: Outcome


SUCCEEDS = Failure(Outcome.SUCCESS, Outcome.SUCCESS)


class ArmedFaults:
    """Per node: callback delays, the next failures and hangs of requested transitions, and a
    rejection of parameter sets. Validation is the caller's; this only keeps and hands out."""

    def __init__(self) -> None:
        self._delays: dict[tuple[str, Transition | None], float] = {}
        self._failures: dict[tuple[str, Transition], Failure] = {}
        self._hangs: set[tuple[str, Transition]] = set()
        self._rejections: dict[str, str] = {}

    def set_delay(self, node: str, seconds: float, transition: Transition | None) -> None:
        self._delays[(node, transition)] = seconds

    def delay(self, node: str, transition: Transition | None, default: float) -> float:
        """The callback delay of ``transition`` (``None``: ``on_error``) at ``node``."""
        per_node = self._delays.get((node, None), default)
        return per_node if transition is None else self._delays.get((node, transition), per_node)

    def fail_next(self, node: str, transition: Transition, failure: Failure) -> None:
        self._failures[(node, transition)] = failure

    def hang_next(self, node: str, transition: Transition) -> None:
        self._hangs.add((node, transition))

    def take_hang(self, node: str, transition: Transition) -> bool:
        """Whether this ``transition`` of ``node`` hangs (the hang is used up)."""
        if (node, transition) in self._hangs:
            self._hangs.discard((node, transition))
            return True
        return False

    def take_failure(self, node: str, transition: Transition) -> Failure:
        """What this ``transition`` of ``node`` returns (an armed failure is used up)."""
        return self._failures.pop((node, transition), SUCCEEDS)

    def reject_parameters(self, node: str, reason: str | None) -> None:
        if reason is None:
            self._rejections.pop(node, None)
        else:
            self._rejections[node] = reason

    def rejection(self, node: str) -> str | None:
        return self._rejections.get(node)

    def clear(self, node: str) -> bool:
        """Disarm the failures, hangs and rejection armed for ``node``; True if there were any."""
        armed = [key for key in self._failures if key[0] == node] + [key for key in self._hangs if key[0] == node]
        for key in armed:
            self._failures.pop(key, None)
            self._hangs.discard(key)
        return bool(armed) | (self._rejections.pop(node, None) is not None)

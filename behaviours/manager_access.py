"""How behaviours reach the embedded mode manager.

Three ways, the first that applies wins:

1. ``ChangeMode(..., manager=manager)``: the behaviour's own (for a tree of several managers);
2. :func:`attach_manager` ``(root, manager)``: every sm_bt behaviour under ``root``, including
   the ones inserted there later while the tree runs (found through their parents);
3. ``tree.setup(manager=manager)``: py_trees' way of handing runtime objects to ``setup``.

The first two also work where ``setup`` gets no keyword arguments (``setup_with_descendants()``,
py_trees_ros before 2.3), and after ``setup``: py_trees_ros makes the tree's node in ``setup``, so
a runtime on that node, and its manager, can only come afterwards. Once it has its manager, a
behaviour checks the part (and mode) it was built for against the manager's model: at set-up
when the manager is known then (a typo fails with the part's real names before anything runs),
otherwise when the behaviour first needs it.
"""

from __future__ import annotations

import weakref
from typing import Any

import py_trees
from py_trees.ports import PortInformation, PortsMixin

from sm_bt.engine.manager import ModeManager
from sm_bt.model.diagnostics import did_you_mean
from sm_bt.model.errors import Error, RequestError
from sm_bt.model.types import DEFAULT_MODE, Model, resolve_mode

#: What sm_bt's behaviours say they are when they ask the manager for a change
#: (:attr:`~sm_bt.engine.requests.Request.requester`).
REQUESTER = "tree"


class NotSetUp(Error, RuntimeError):
    """A behaviour needed its mode manager and none was given (see the module's three ways)."""


def _hint(behaviour: py_trees.behaviour.Behaviour) -> str:
    return (f"{behaviour.qualified_name}: no mode manager; give it one: "
            "sm_bt.behaviours.attach_manager(root, manager) on its tree or subtree, "
            "tree.setup(manager=manager), or the behaviour's manager= argument")


#: Managers attached to subtrees, by the subtree's root (kept only while the root lives).
_attached: weakref.WeakKeyDictionary[py_trees.behaviour.Behaviour, ModeManager] = weakref.WeakKeyDictionary()


def _require_manager(owner: str, manager: object) -> ModeManager:
    if not isinstance(manager, ModeManager):
        raise TypeError(f"{owner}: manager= must be a ModeManager, not {type(manager).__name__}")
    return manager


def attach_manager(root: py_trees.behaviour.Behaviour, manager: ModeManager) -> py_trees.behaviour.Behaviour:
    """Make ``manager`` the mode manager of every sm_bt behaviour under ``root`` (``root``
    included), now and for subtrees inserted under it later; returns ``root``.

    Behaviours given their own ``manager=`` keep it; a manager attached to a deeper subtree
    wins for that subtree. Parts and modes are checked when each behaviour is set up (or, if it
    never is, first ticked)."""
    _attached[root] = _require_manager(f"attach_manager({root.name!r})", manager)
    return root


def attached_manager(behaviour: py_trees.behaviour.Behaviour) -> ModeManager | None:
    """The manager attached to ``behaviour`` or its nearest ancestor, if any."""
    node: py_trees.behaviour.Behaviour | None = behaviour
    while node is not None:
        manager = _attached.get(node)
        if manager is not None:
            return manager
        node = node.parent
    return None


def require_mode_name(behaviour: str, part: str, mode: str) -> None:
    """:class:`~sm_bt.RequestError` for an empty mode name: ``__DEFAULT__`` is the explicit name of the
    default."""
    if not mode:
        raise RequestError(f"{behaviour}: the mode name of {part} is empty (name a mode, or {DEFAULT_MODE} "
                           "for the default mode)")


def seconds(owner: str, value: float | str | None, what: str = "timeout") -> float | None:
    """``value`` as positive seconds (``None`` stays ``None``); XML gives text, so ``"10"`` is
    10.0. ``ValueError`` naming ``owner`` for anything else."""
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}: {what} must be a number of seconds, not {value!r}") from None
    if not number > 0 or number == float("inf"):
        raise ValueError(f"{owner}: {what} must be positive, not {value}")
    return number


def flag(owner: str, value: bool | str, what: str) -> bool:
    """``value`` as a bool; XML gives ``"true"``/``"false"``."""
    if isinstance(value, bool):
        return value
    text = str(value).strip().lower()
    if text in ("true", "1", "yes"):
        return True
    if text in ("false", "0", "no"):
        return False
    raise ValueError(f"{owner}: {what} must be true or false, not {value!r}")


class ManagerBehaviour(PortsMixin, py_trees.behaviour.Behaviour, register=False):
    """A behaviour that works through a :class:`ModeManager`.

    ``manager`` (optional) is the behaviour's own; otherwise :func:`attach_manager` on an
    ancestor, otherwise ``setup(manager=...)``. ``setup`` validates the behaviour's configuration
    against the model of the manager it finds (see :meth:`check_model`: ``ValueError`` for a part or
    mode the model does not have); with none yet (a manager attached after set-up), the behaviour
    finds and checks it when it first needs it, and raises :class:`NotSetUp` there if there is
    still none.

    Every sm_bt behaviour is a py_trees ports node (:class:`~py_trees.ports.PortsMixin`), so
    py_trees' XML parser builds it by its class name; ``kwargs`` go to it (the parser's
    ``behaviour_class_name``).
    """

    # py_trees declares these as plain class attributes, read only (no ClassVar there either).
    INPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012
    OUTPUT_PORTS: dict[str, PortInformation] = {}  # noqa: RUF012


    def __init__(self, name: str, *, manager: ModeManager | None = None, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self._own = _require_manager(name, manager) if manager is not None else None
        self._manager: ModeManager | None = None

    #: Ports the behaviour wires to the blackboard itself (see :meth:`wire_port`).
    WIRED_PORTS: frozenset[str] = frozenset()

    def setup_ports(self, port_remappings: dict[str, str] | None = None, subtree_namespace: str = "/",
                    logger: Any = None) -> None:
        """The XML parser's wiring. sm_bt's own ports go to :meth:`wire_port` (no extra blackboard
        client per behaviour); other declared ports (a subclass's) get py_trees' handling."""
        remappings = dict(port_remappings or {})
        declared = set(self.input_ports()) | set(self.output_ports())
        for port in remappings:
            if port not in declared:
                raise KeyError(f"{self.name}: no port {port!r} (ports: {', '.join(sorted(declared)) or 'none'})")
        for port in [p for p in remappings if p in self.WIRED_PORTS]:
            self.wire_port(port, py_trees.blackboard.Blackboard.absolute_name(subtree_namespace, remappings.pop(port)))
        if declared - self.WIRED_PORTS:
            super().setup_ports(remappings, subtree_namespace, logger)
        else:
            self._subtree_namespace = subtree_namespace

    def wire_port(self, port: str, key: str) -> None:
        """Connect one of :attr:`WIRED_PORTS` to the absolute blackboard ``key``."""
        raise NotImplementedError(port)

    def setup(self, **kwargs: Any) -> None:
        given = kwargs.get("manager")
        manager = self._own or attached_manager(self) or given
        if manager is not None:  # else attached later, before the first tick (py_trees_ros' order)
            self._use(_require_manager(self.qualified_name, manager))

    def _use(self, manager: ModeManager) -> None:
        self.check_model(manager.model)
        self._manager = manager

    @property
    def detail(self) -> str:
        """What it works on, in a few words (``"pilot f_degraded_mode"``): viewers show it in the
        behaviour's box, since they cut names short."""
        return ""

    @property
    def manager(self) -> ModeManager:
        """The manager (found and validated on first use if ``setup`` did not run)."""
        if self._manager is None:
            manager = self._own or attached_manager(self)
            if manager is None:
                raise NotSetUp(_hint(self))
            self._use(manager)
            assert self._manager is not None
        return self._manager

    def check_model(self, model: Model) -> None:
        """Check the configuration against ``model`` (parts, modes); :class:`~sm_bt.RequestError` (a
        ``ValueError``) if it is wrong, as the manager would raise for the request. Needs no
        manager: ``sm-bt check`` runs it on tree files."""

    # -- shared checks -------------------------------------------------------------------------

    def _check_part(self, model: Model, part: str) -> None:
        if part not in model.parts:
            raise RequestError(f"{self.qualified_name}: unknown part {part!r}{did_you_mean(part, model.parts)} "
                               f"(parts: {', '.join(model.parts)})")

    def _check_mode(self, model: Model, part: str, mode: str) -> str:
        """The mode name ``mode`` stands for (``__DEFAULT__`` is the part's default mode)."""
        self._check_part(model, part)
        require_mode_name(self.name, part, mode)
        spec = model.parts[part]
        resolved = resolve_mode(spec, mode)
        if resolved is not None:
            return resolved
        raise RequestError(f"{self.qualified_name}: {part} has no mode {mode!r}{did_you_mean(mode, spec.modes)} "
                           f"(modes: {', '.join(sorted(spec.modes))})")

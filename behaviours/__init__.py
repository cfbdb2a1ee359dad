"""Mode behaviours for py_trees (installed as ``sm_bt.behaviours``).

Every behaviour finds the embedded :class:`~sm_bt.ModeManager` through its own ``manager=``,
:func:`attach_manager` on its tree or subtree, or ``tree.setup(manager=manager)``, and never
blocks a tick:

* :class:`ChangeMode`, :class:`ChangeState`: request a change, RUNNING until confirmed
* :class:`CanChangeMode`: could a change be made now (a preview: nothing is asked)
* :class:`ModeIs`, :class:`StateIs`: checks (SUCCESS/FAILURE in one tick)
* :class:`WaitForMode`, :class:`WaitForState`: wait until the part gets there
* :class:`OnDivergence`: a condition on a part straying from its target
* :class:`ModesToBlackboard`: every part's state and mode under ``/system_modes``
* :class:`Reconfigure`: let a :class:`~sm_bt.reasoner.Reasoner` pick and request the mode
* idioms: :func:`hold_mode` (context switch), :func:`switch_on_divergence` (rule in the tree)
* :class:`FeedbackSnapshotVisitor`: snapshots flagged changed on a new step of a change too
"""

from sm_bt.behaviours.blackboard import ModesToBlackboard, PartStatus
from sm_bt.behaviours.change import TRANSITIONS, CanChangeMode, ChangeMode, ChangeState
from sm_bt.behaviours.checks import ModeIs, StateIs, WaitForMode, WaitForState
from sm_bt.behaviours.divergence import OnDivergence
from sm_bt.behaviours.idioms import (
    HoldMode,
    HoldModeSubtree,
    SwitchOnDivergenceSubtree,
    hold_mode,
    switch_on_divergence,
)
from sm_bt.behaviours.manager_access import ManagerBehaviour, NotSetUp, attach_manager
from sm_bt.behaviours.reconfigure import Reconfigure
from sm_bt.behaviours.visitors import FeedbackSnapshotVisitor

__all__ = [
    "TRANSITIONS",
    "CanChangeMode",
    "ChangeMode",
    "ChangeState",
    "FeedbackSnapshotVisitor",
    "HoldMode",
    "HoldModeSubtree",
    "ManagerBehaviour",
    "ModeIs",
    "ModesToBlackboard",
    "NotSetUp",
    "OnDivergence",
    "PartStatus",
    "Reconfigure",
    "StateIs",
    "SwitchOnDivergenceSubtree",
    "WaitForMode",
    "WaitForState",
    "attach_manager",
    "hold_mode",
    "switch_on_divergence",
]

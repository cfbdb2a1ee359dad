"""A fleet's shift as a mission tree: the fleet model's modes (``models/fleet.yaml``: two robots, each
a manager of its own) asked of the fleet's manager, never of a robot.

``create_root()``: the day shift (``fleet`` in ``__DEFAULT__``: both robots active), then wait for
the night (``NIGHT``: robot1 in its energy-saving mode, robot2 at rest), which the fleet's own rule
asks when robot1 is lost (``robot1_lost``), and end the shift (``fleet`` deactivated: every robot
inactive). The demo (:mod:`sm_bt.trees.fleet.demo`) cuts robot1 off and heals it meanwhile.
"""

from __future__ import annotations

import py_trees

from sm_bt.behaviours import ChangeMode, ChangeState, WaitForMode

#: The fleet's top system in the bundled model.
FLEET = "fleet"
#: The longest the tree waits for the night (seconds of the manager's clock).
NIGHT_WITHIN = 60.0
#: The demo's virtual seconds per wall second by default: the shift takes about two seconds to watch.
DEMO_SPEED = 4.0


def create_root() -> py_trees.behaviour.Behaviour:
    """The shift: day shift, the night (asked by the fleet's rule), end of shift."""
    return py_trees.composites.Sequence("fleet shift", memory=True, children=[
        ChangeMode("day shift", part=FLEET, mode="__DEFAULT__"),
        WaitForMode("until the night", part=FLEET, mode="NIGHT", timeout=NIGHT_WITHIN),
        ChangeState("end of shift", part=FLEET, transition="deactivate"),
    ])

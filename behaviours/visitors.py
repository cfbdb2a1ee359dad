"""A snapshot visitor that also counts feedback: a long mode change shows each new step.

py_trees' :class:`~py_trees.visitors.SnapshotVisitor` flags a tick as ``changed`` only when a
status on the visited path changed. A ``ChangeMode`` stays RUNNING for the whole change while
its feedback names the step in progress, so a snapshot stream that publishes only on change (the
tree watcher's default) never shows those steps. :class:`FeedbackSnapshotVisitor` flags a
change of feedback too; use it wherever a ``SnapshotVisitor`` decides when to publish.
"""

from __future__ import annotations

import uuid

import py_trees


class FeedbackSnapshotVisitor(py_trees.visitors.SnapshotVisitor):
    """``changed`` when a status *or a feedback message* on the visited path changed since the
    previous tick; ``status_changed`` for the first alone (py_trees' ``changed``), so that a
    publisher may send status changes at once and pace feedback-only ones. ``feedback`` and
    ``previous_feedback`` hold the messages by behaviour id."""

    def __init__(self) -> None:
        super().__init__()
        self.status_changed = False
        self.feedback: dict[uuid.UUID, str] = {}
        self.previous_feedback: dict[uuid.UUID, str] = {}

    def initialise(self) -> None:
        super().initialise()
        self.status_changed = False
        self.previous_feedback, self.feedback = self.feedback, {}

    def run(self, behaviour: py_trees.behaviour.Behaviour) -> None:
        feedback_changed = self.changed and not self.status_changed
        self.changed = self.status_changed
        super().run(behaviour)
        self.status_changed = self.changed
        message = behaviour.feedback_message
        self.feedback[behaviour.id] = message
        if self.previous_feedback.get(behaviour.id, message) != message:
            feedback_changed = True
        self.changed = self.status_changed or feedback_changed

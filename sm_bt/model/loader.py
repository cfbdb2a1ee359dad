"""Load and validate an SMH ("system modes and hierarchy") model file.

The format is the one of the C++ reference (micro-ROS/system_modes), which reads the file as a
ROS 2 parameter file; a file the reference accepts and gets right loads here unchanged::

    actuation:                      # a part; "ns/name:" or "ns: {name: ...}" give namespaced names
      ros__parameters:
        type: system                # exactly "node" or "system"
        parts:                      # optional; if given it must agree with the modes
          manipulator
          drive_base
        defaultmode: __DEFAULT__    # optional; else the mode named __DEFAULT__ is the default
        modes:
          __DEFAULT__:
            manipulator: inactive   # state[.MODE]; "active" alone means the part's default mode
            drive_base: active
          PERFORMANCE:              # parts left out inherit the default mode's entry
            manipulator: active.STRONG
        rules:                      # sorted by name, as the reference evaluates them
          degrade:
            if_target: active.PERFORMANCE
            if_part: [manipulator, inactive]
            new_target: active      # __DEFAULT__ also names the default mode
    manipulator:
      ros__parameters:
        type: node
        modes:
          __DEFAULT__:
            ros__parameters: {max_torque: 0.1}
          STRONG:                   # a delta: unlisted parameters keep the default value
            ros__parameters: {max_torque: 0.2}

Unlike the reference, everything is checked up front and every error is reported with its line
and what to change: unknown parts (with a "did you mean"), upper-case or unknown state labels,
unknown modes, parameters missing from the default mode or of another type, missing ``type``
or default mode, cycles in the hierarchy, malformed rules. Ambiguous node modes (inference
could not tell them apart) and unknown keys are warnings, in :attr:`Model.warnings`.

Extensions (the reference does not know them; it would misread a file that uses them):

1. **Don't care.** A system-mode entry ``part: __DONTCARE__`` leaves the part as it is when the
   system switches to that mode, and any state of the part matches during inference
   (``PartEntry.target is None``).
2. **Inference matching** (nodes only). ``match:`` beside ``modes:`` applies to every mode of the
   node; ``match:`` inside a mode, beside its ``ros__parameters:``, overrides it parameter by
   parameter for that mode. Each entry is ``param: {tolerance: EPS}``, ``param: [MIN, MAX]``
   (closed range) or ``param: {min: A, max: B}`` (either bound optional; ``tolerance`` may be
   combined with them); nested maps give dotted names as in ``ros__parameters``. Only numeric
   parameters may have one; a mode's own value must lie inside its range. Parameters without an
   entry compare exactly.
3. **Switching order** (systems only). A system mode may hold ``__order__: [STAGE, ...]``, each
   stage a string of one or more of the system's parts separated by commas, e.g.
   ``__order__: ["pointcloud_to_laser", "amcl, controller_server"]``. Stages switch one after
   another, the parts of one stage in parallel; parts not named form one last stage. A mode
   without ``__order__`` uses its default mode's order; with none anywhere, all parts switch
   together (as in the reference). Stored as ``SystemMode.stages``.
4. **defaultmode** (from the reference's unreleased ``refactoring`` branch): any mode can be the
   default; ``__DEFAULT__`` in entries and rules then names that mode.

Details worth knowing: scalars are typed as rcl types them (``010`` is the integer 8, ``1e3`` a
double, ``yes``/``on`` booleans; quote a value or tag it ``!!str`` to keep it a string). Targets
(system-mode entries, ``if_target``, ``new_target``) must be states a part can rest in
(``unconfigured``, ``inactive``, ``active``, ``finalized``); ``if_part`` may name any lifecycle
state, e.g. ``errorprocessing``, and any part below the system (nested parts included). A
leading ``/`` on a part name (root namespace) is ignored everywhere.

``strict=False`` turns one error into a warning: a system-mode entry naming a part that is not
defined (the reference's own ``example_modes_with_namespace.yaml`` has such a typo); the entry
is dropped.
"""

from __future__ import annotations

import dataclasses
import os

from sm_bt.model.declarations import PartDecl, read_declarations
from sm_bt.model.diagnostics import Diagnostics
from sm_bt.model.errors import ModelError
from sm_bt.model.gc_tuning import gc_paused
from sm_bt.model.hierarchy import parts_below, report_cycles
from sm_bt.model.node_modes import build_node
from sm_bt.model.rcl_yaml import parse_document
from sm_bt.model.rules import build_rules
from sm_bt.model.system_modes import build_system
from sm_bt.model.types import Location, Model, ModelIssue, Part, PartKind, Severity


def load_model(path: str | os.PathLike[str], *, strict: bool = True) -> Model:
    """Load the model file at ``path``; raise :class:`ModelError` with every problem found."""
    filename = os.fspath(path)
    try:
        with open(filename, "rb") as stream:
            data = stream.read()
    except OSError as exc:
        raise ModelError([ModelIssue(Location(filename, 0), Severity.ERROR,
                                     f"cannot read the model file: {exc.strerror or exc}: check the path")]) from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:  # where the bad byte is: the line and column a user can find
        line = data.count(b"\n", 0, exc.start) + 1
        column = exc.start - (data.rfind(b"\n", 0, exc.start) + 1) + 1
        raise ModelError([ModelIssue(Location(filename, line), Severity.ERROR,
                                     f"byte 0x{data[exc.start]:02x} at column {column} is not UTF-8: save the "
                                     "file as UTF-8 text")]) from None
    return load_model_text(text, filename, strict=strict)


def load_model_text(text: str, filename: str = "<string>", *, strict: bool = True) -> Model:
    """Load a model from its text; ``filename`` is used in the issues' locations."""
    diag = Diagnostics(filename)
    parts: dict[str, Part] = {}
    with gc_paused():
        doc = parse_document(text, diag)
        if doc is not None:
            decls = read_declarations(doc, diag)
            del doc  # the declarations hold what is needed: _build lets the text tree go as it goes
            parts = _build(decls, diag, strict)
    diag.raise_if_errors()
    return Model(filename, parts, diag.sorted_warnings())


def _build(decls: dict[str, PartDecl], diag: Diagnostics, strict: bool) -> dict[str, Part]:
    built: dict[str, Part] = {}
    for decl in decls.values():
        part: Part | None = None
        if decl.kind is PartKind.NODE:
            part = build_node(decl, diag)
            decls[decl.name] = decl.outline()  # a big file's peak memory: its text and its model at once
        elif decl.kind is PartKind.SYSTEM:
            part = build_system(decl, decls, diag, strict=strict)
        if part is not None:
            built[decl.name] = part
    children = {name: part.parts for name, part in built.items()}
    if not report_cycles(children, {name: decl.line for name, decl in decls.items()}, diag):
        return built
    for name, part in built.items():
        below = parts_below(name, children) if part.kind is PartKind.SYSTEM else (name,)
        rules = build_rules(decls[name], decls, below, diag)
        if rules:
            built[name] = dataclasses.replace(part, rules=rules)
    return built

"""The side-by-side report of ``make interop`` (tests/interop/harness.py), in Markdown.

First a summary (the table docs/reference.md quotes), then one table per scenario: for every step, what
each manager answered, when ``get_state``/``get_mode`` showed the expected value, when the event
topic did, and, where it did not, where the part ended up.
"""

from __future__ import annotations

import statistics
from collections.abc import Iterable
from typing import Any

MANAGERS = ("sm-bt manager", "reference")


def _ms(seconds: float | None) -> str:
    if seconds is None:
        return "never"
    return f"{seconds * 1000:.0f} ms" if seconds < 1 else f"{seconds:.2f} s"


def _step_name(step: dict[str, Any]) -> str:
    if "change_mode" in step:
        return f"change_mode {step['change_mode']} {step['mode']}"
    if "change_state" in step:
        label = "" if step.get("id", True) else " (label only, id 0)"
        return f"change_state {step['change_state']} {step['transition']}{label}"
    if "node_change_state" in step:
        return f"{step['node_change_state']}'s own change_state {step['transition']} (behind the manager)"
    return f"a late transient-local subscriber to /{step['late_subscriber']}/*_event"


def _cell(result: dict[str, Any]) -> str:
    step = result["step"]
    if "late_subscriber" in step:
        heard = [f"{topic} {text}" for _, topic, text in result["heard"]]
        return "hears " + "; ".join(heard) if heard else "hears nothing"
    if result["answer"] is None:
        return "no answer"
    if step.get("expect", "") is None:
        return f"answers {str(result['answer']).lower()}"
    answers = result["answers"]
    if "node_change_state" in step:
        before = result.get("system_mode_before")
        trail = ", ".join(f"{value!r} at {_ms(at)}" for at, value in answers)
        restored = len(answers) > 1 and answers[-1][1] == before
        return f"get_mode: {trail}" + (" (restored)" if restored else " (not restored)")
    text = f"{str(result['answer']).lower()} in {_ms(result['answered_s'])}; get: {_ms(result['shown_s'])}; " \
           f"event: {_ms(result['told_s'])}"
    if result.get("nodes_done_s") is not None:
        text += f"; nodes done: {_ms(result['nodes_done_s'])}"
        if early_by(result) is not None:
            text += " (**shown before**)"
    if result["shown_s"] is None:
        text += f"; stays {answers[-1][1]!r}" if answers else ""
    return text


#: How much earlier than the nodes' own event a manager may show a change (it may hear the
#: node's answer to change_state before the client hears the node's event).
EARLY_TOLERANCE = 0.05


def early_by(result: dict[str, Any]) -> float | None:
    """How long before the nodes got there a step's change was shown (None: not before, or not a
    change asked of the manager)."""
    step = result.get("step", {})
    if "change_mode" not in step and "change_state" not in step:
        return None
    done = result.get("nodes_done_s")
    shown = [t for t in (result.get("shown_s"), result.get("told_s")) if t is not None]
    if done is None or not shown or min(shown) >= done - EARLY_TOLERANCE:
        return None
    return float(done - min(shown))


def _by(results: Iterable[dict[str, Any]]) -> dict[tuple[str, str], dict[str, Any]]:
    return {(r["scenario"], r["manager"]): r for r in results}


def _steps(run: dict[str, Any] | None) -> list[dict[str, Any]]:
    return [] if run is None or "steps" not in run else list(run["steps"])


def _median(values: list[float]) -> str:
    return _ms(statistics.median(values)) if values else "never"


def _summary(runs: dict[tuple[str, str], dict[str, Any]], scenarios: list[str]) -> list[str]:
    rows: list[tuple[str, list[str]]] = []

    def row(label: str, value: Any) -> None:
        rows.append((label, [value(runs.get(("pilot", m))) for m in MANAGERS]))

    def bring_up(run: dict[str, Any] | None, key: str, count: int = 3) -> str:
        steps = _steps(run)[:count]
        if len(steps) < count or any(s[key] is None for s in steps):
            return "never"
        return _ms(sum(s[key] for s in steps))

    def switches(run: dict[str, Any] | None, key: str) -> str:
        values = [s[key] for s in _steps(run)[3:8]]
        missing = sum(v is None for v in values)
        return _median([v for v in values if v is not None]) + (f" ({missing} never)" if missing else "")

    def find(run: dict[str, Any] | None, predicate: Any) -> dict[str, Any] | None:
        return next((s for s in _steps(run) if predicate(s["step"])), None)

    row("bring-up (configure, activate, f_normal_mode): `get_*` shows it", lambda r: bring_up(r, "shown_s"))
    row("bring-up: the events show it", lambda r: bring_up(r, "told_s"))
    row("mode switch (median of 5): `get_mode` shows it", lambda r: switches(r, "shown_s"))
    row("mode switch: `mode_event` shows it", lambda r: switches(r, "told_s"))
    slow = [runs.get(("pilot-slow", m)) for m in MANAGERS]
    rows.append(("bring-up with 2 s transitions: `get_*` shows it", [bring_up(r, "shown_s") for r in slow]))
    rows.append(("bring-up with 2 s transitions: the events show it", [bring_up(r, "told_s") for r in slow]))

    def degraded(run: dict[str, Any] | None) -> str:
        step = find(run, lambda s: s.get("mode") == "f_degraded_mode")
        return "—" if step is None else ("reached in " + _ms(step["shown_s"]) if step["shown_s"] is not None
                                         else f"never: pilot stays {step['after']['manager']['pilot']['state']}, "
                                              f"mode {step['after']['manager']['pilot']['mode']!r}")

    def label_only(run: dict[str, Any] | None) -> str:
        step = find(run, lambda s: s.get("id") is False)
        if step is None:
            return "—"
        after = step["after"]["manager"][step["step"]["change_state"]]
        return (f"done in {_ms(step['shown_s'])}" if step["shown_s"] is not None
                else f"fails: the system becomes {after['state']}, mode {after['mode']!r}")

    def late(run: dict[str, Any] | None) -> str:
        step = find(run, lambda s: "late_subscriber" in s)
        if step is None:
            return "—"
        modes = [text for _, topic, text in step["heard"] if topic == "mode_event"]
        return f"gets the current mode ({modes[-1]})" if modes else "gets nothing (volatile publisher)"

    def behind(run: dict[str, Any] | None) -> str:
        step = find(run, lambda s: "node_change_state" in s)
        if step is None:
            return "—"
        answers, before = step["answers"], step.get("system_mode_before")
        left = next((at for at, value in answers if value != before), None)
        back = next((at for at, value in answers[1:] if value == before), None) if left is not None else None
        return f"noticed in {_ms(left)}" + (f", restored in {_ms(back)}" if back is not None else ", not restored")

    def early(scenario: str, manager: str) -> str:
        leads = [lead for step in _steps(runs.get((scenario, manager))) if (lead := early_by(step)) is not None]
        return f"{len(leads)}, by up to {_ms(max(leads))}" if leads else "none"

    rows.append(("changes shown before the nodes got there (with 2 s transitions)",
                 [early("pilot-slow", m) for m in MANAGERS]))
    row("f_degraded_mode (a part to unconfigured)", degraded)
    row("`change_state` with a label and id 0", label_only)
    row("a subscriber that joins late (transient local)", late)
    row("a node deactivated behind the manager's back", behind)
    row("transitions the nodes refused (sent in a state that has none)",
        lambda r: "—" if r is None else str(r["refused_by_nodes"]))
    row("exit on SIGINT", lambda r: "—" if r is None else ("0" if r["manager_exit"] == 0
                                                           else f"{r['manager_exit']} (abort)"))
    own = [name for name in scenarios if name not in ("pilot", "pilot-slow")]

    def own_models(manager: str) -> str:
        total = shown = told = impossible = 0
        for name in own:
            for step in _steps(runs.get((name, manager))):
                if step["step"].get("fails"):  # a plain node asked to be configured
                    impossible += 1
                elif step.get("expect") is not None and "shown_s" in step:
                    total += 1
                    shown += step["shown_s"] is not None
                    told += step["told_s"] is not None
        if not total:
            return "—"
        return (f"{shown}/{total} shown by `get_*`, {told}/{total} by events"
                + (f" (and {impossible} that cannot be made: a plain node to configure)" if impossible else ""))

    if own:
        rows.append((f"the reference's own models ({len(own)}): changes", [own_models(m) for m in MANAGERS]))
    lines = ["| pilot, measured | " + " | ".join(f"`{m}`" if m != "reference" else "reference `mode_manager`"
                                               for m in MANAGERS) + " |", "|---|---|---|"]
    lines += [f"| {label} | " + " | ".join(values) + " |" for label, values in rows]
    return lines


def write_report(results: list[dict[str, Any]], titles: dict[str, str]) -> str:
    runs = _by(results)
    out = ["# sm_bt and the reference, measured (`make interop`)", "",
           "The same plain-rclpy client (tests/interop/client.py) against `sm-bt manager` and the reference's "
           "`mode_manager`, on the same simulated nodes and model files. Times are from the request; `get_*` is "
           "the first `get_state`/`get_mode` answer (asked every 20 ms) that shows the change, event the first "
           "`transition_event`/`mode_event`.", ""]
    out += _summary(runs, list(titles))
    for name, title in titles.items():
        out += ["", f"## {title}", ""]
        for manager in MANAGERS:
            run = runs.get((name, manager))
            if run is not None and "error" in run:
                out.append(f"- {manager}: **error**: {run['error']}")
        pairs = [_steps(runs.get((name, m))) for m in MANAGERS]
        if not any(pairs):
            continue
        out += ["| step | `sm-bt manager` | reference |", "|---|---|---|"]
        for index in range(max(len(p) for p in pairs)):
            cells = [_cell(p[index]) if index < len(p) else "—" for p in pairs]
            step = next(p[index]["step"] for p in pairs if index < len(p))
            out.append(f"| {_step_name(step)} | " + " | ".join(cells) + " |")
        ended = [runs[(name, m)] for m in MANAGERS if (name, m) in runs and "steps" in runs[(name, m)]]
        extra = [f"{run['manager']}: nodes refused {run['refused_by_nodes']} transitions, exit {run['manager_exit']}"
                 for run in ended]
        out += ["", "; ".join(extra) + "."]
    return "\n".join(out) + "\n"

"""The scripted pilot demo tells the whole story and ends as expected."""

from __future__ import annotations

from sm_bt.cli import main
from sm_bt.demo import Demo, Options


def test_demo_story() -> None:
    lines: list[str] = []
    assert Demo(Options(laser_failure_at=12.0, battery_low_at=30.0, speed=0, quiet=False), lines.append).run() == 0
    text = "\n".join(lines)
    assert "f_performance_mode failed: controller_server: set parameters of mode FAST failed" in text
    assert "rule degrade_from_normal: laser_resender is unconfigured -> active.f_degraded_mode" in text
    assert "pilot                active        active(*)     f_degraded_mode" in text
    assert "pilot ends in active.f_normal_mode; as expected" in text


def test_demo_failure_times_are_options(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["demo", "--speed", "0", "--laser-failure-at", "5", "--battery-low-at", "20"]) == 0
    out = capsys.readouterr().out
    assert "[  5.00 s] Laser failure" in out or "[   5.00 s] Laser failure" in out


def test_demo_quiet_prints_only_the_summary(capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(["demo", "--speed", "0", "--quiet"]) == 0
    out = capsys.readouterr().out
    assert out.lstrip().startswith("Summary") and "Laser failure" not in out

"""Log lines for operators in ROS 2's console format, to stderr.

``[INFO] [1700000000.123456] [sm_bt.manager]: message``: what ``sm-bt manager`` and the mission
host print, one line per event an operator needs. The library itself never configures logging;
only these programs call :func:`configure_logging`. Needs no rclpy.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

#: ``--log-level`` choices.
LOG_LEVELS = {"debug": logging.DEBUG, "info": logging.INFO, "warning": logging.WARNING, "error": logging.ERROR}
#: ROS 2's severity names where they differ from Python's.
_SEVERITY = {"WARNING": "WARN", "CRITICAL": "FATAL"}


class RosFormatter(logging.Formatter):
    """ROS 2's console format: ``[SEVERITY] [seconds.micro] [logger]: message``."""

    def format(self, record: logging.LogRecord) -> str:
        severity = _SEVERITY.get(record.levelname, record.levelname)
        line = f"[{severity}] [{record.created:.6f}] [{record.name}]: {record.getMessage()}"
        if record.exc_info:
            line += "\n" + self.formatException(record.exc_info)
        return line


class _Handler(logging.StreamHandler):  # type: ignore[type-arg]
    """The handler :func:`configure_logging` installs (so that calling it again replaces it)."""


def configure_logging(level: str, stream: TextIO | None = None) -> None:
    """Log from ``level`` (a ``--log-level`` choice) on to ``stream`` (stderr) in ROS 2's format,
    through the root logger; replaces what an earlier call installed."""
    root = logging.getLogger()
    for handler in [h for h in root.handlers if isinstance(h, _Handler)]:
        root.removeHandler(handler)
    handler = _Handler(sys.stderr if stream is None else stream)
    handler.setFormatter(RosFormatter())
    root.addHandler(handler)
    root.setLevel(LOG_LEVELS[level])

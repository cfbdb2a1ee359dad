"""``python -m bench [--quick] [--only NAMES] [--out DIR]``: run the benchmarks, print the table.

Exit status 0 when every goal is met, 1 when one is not or a benchmark module failed, 2 for a
usage error. Progress goes to stderr; stdout is the table (markdown, as in docs/performance.md).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from bench.figures import Figure
from bench.report import plot, table, write_json

#: In the order they run: the cheap, deterministic ones first, the real-ROS ones last (a fleet of 10
#: robots, 20 processes, takes about 2.5 minutes).
MODULES = ("scale", "memory", "model_load", "large", "tick", "analysis", "ros", "ros_app", "cli", "ros_fleet")
#: Run only when named (``--only``): 200 real nodes in ten processes take 3-4 minutes on their own.
OPTIONAL = ("ros_plant",)


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0] if text else ''}".rstrip(": ")


class ModuleFailed(RuntimeError):
    """A benchmark module's process failed; the message is its last line of stderr."""


def _run_module(name: str, quick: bool) -> list[Figure]:
    """Run ``bench.<name>`` in a fresh interpreter (see :mod:`bench.one`)."""
    if name not in MODULES + OPTIONAL:
        raise LookupError(f"no benchmark module {name!r} (modules: {', '.join(MODULES + OPTIONAL)})")
    command = [sys.executable, "-m", "bench.one", name, *(["--quick"] if quick else [])]
    done = subprocess.run(command, cwd=Path(__file__).resolve().parents[1], capture_output=True, text=True,
                          timeout=1800, check=False)
    if done.returncode != 0:
        lines = [line for line in done.stderr.strip().splitlines() if line.strip()]
        raise ModuleFailed(lines[-1] if lines else f"exit status {done.returncode}")
    figures = []
    for item in json.loads(done.stdout.strip().splitlines()[-1]):
        item.pop("met", None)
        figures.append(Figure(**item))
    return figures


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, a few seconds per module (smoke test)")
    parser.add_argument("--only", default="", metavar="NAMES",
                        help=f"comma-separated modules to run (default: all of {', '.join(MODULES)}; "
                        f"also {', '.join(OPTIONAL)})")
    parser.add_argument("--out", type=Path, default=Path("build/bench"), help="where results.json and "
                        "scaling.png go (default: build/bench)")
    args = parser.parse_args(argv)
    names = [name.strip() for name in args.only.split(",") if name.strip()] or list(MODULES)
    args.out.mkdir(parents=True, exist_ok=True)

    figures: list[Figure] = []
    failures: list[tuple[str, str]] = []
    started = time.monotonic()
    for name in names:
        print(f"bench: {name} ...", file=sys.stderr, flush=True)
        began = time.monotonic()
        try:
            got = _run_module(name, args.quick)
        except Exception as error:  # one broken benchmark must not hide the others' figures
            failures.append((name, _one_line(error)))
            print(f"bench: {name} failed: {_one_line(error)}", file=sys.stderr, flush=True)
            continue
        figures.extend(got)
        print(f"bench: {name} done in {time.monotonic() - began:.0f} s", file=sys.stderr, flush=True)
    duration = time.monotonic() - started

    print(table(figures, failures))
    write_json(args.out / "results.json", figures, failures, duration, args.quick)
    drawn = plot(args.out / "scaling.png", figures)
    print(f"bench: {len(figures)} figures in {duration:.0f} s; results in {args.out / 'results.json'}"
          + (f", plot in {args.out / 'scaling.png'}" if drawn else " (no scaling figures: no plot)"),
          file=sys.stderr)
    unmet = [f for f in figures if f.met is False]
    return 1 if unmet or failures else 0


if __name__ == "__main__":
    sys.exit(main())

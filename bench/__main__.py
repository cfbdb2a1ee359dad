"""``python -m bench [--quick] [--only NAMES] [--out DIR]``: run the benchmarks, print the table.

Exit status 0 when every goal is met, 1 when one is not or a benchmark module failed, 2 for a
usage error. Progress goes to stderr; stdout is the table (markdown, as in the README).
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

from bench.figures import Figure
from bench.report import plot, table, write_json

#: In the order they run: the cheap, deterministic ones first, the real-ROS one last.
MODULES = ("scale", "memory", "model_load", "tick", "ros")


def _one_line(error: BaseException) -> str:
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}: {text[0] if text else ''}".rstrip(": ")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench", description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="small sizes, a few seconds per module (smoke test)")
    parser.add_argument("--only", default="", metavar="NAMES",
                        help=f"comma-separated modules to run (default: all of {', '.join(MODULES)})")
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
            if name not in MODULES:
                raise LookupError(f"no benchmark module {name!r} (modules: {', '.join(MODULES)})")
            module = importlib.import_module(f"bench.{name}")
            got = module.run(args.quick)
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

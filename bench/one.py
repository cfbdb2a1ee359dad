"""``python -m bench.one NAME [--quick]``: run one benchmark module, print its figures as JSON.

The harness runs every module this way, each in a fresh interpreter: what one module leaves
behind (a 10,000-node model, its garbage) must not weigh on the next one's figures.
"""

from __future__ import annotations

import importlib
import json
import sys


def main(argv: list[str]) -> int:
    name, quick = argv[0], "--quick" in argv[1:]
    module = importlib.import_module(f"bench.{name}")
    figures = module.run(quick)
    print(json.dumps([figure.as_json() for figure in figures]))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

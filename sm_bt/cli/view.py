"""``sm-bt view FILE.jsonl``: replay a recorded run in the browser (tree, modes, timeline)."""

from __future__ import annotations

import argparse
import time

from sm_bt.cli.arguments import non_negative
from sm_bt.cli.common import CliError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="FILE.jsonl", help="a run recorded with `sm-bt demo --record FILE.jsonl`")
    parser.add_argument("--port", type=int, default=8765, help="port to serve on (default 8765; 0: any free port)")
    parser.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    parser.add_argument("--at", type=non_negative, default=None, metavar="SECONDS",
                        help="open the page at this moment of the run (sm-bt test prints the one where a scenario "
                             "first failed)")


def run(args: argparse.Namespace) -> int:
    from sm_bt.view import read_recording
    from sm_bt.view.server import ViewServer

    try:
        frames = read_recording(args.recording)
    except OSError as error:
        raise CliError(f"cannot read {args.recording}: {error.strerror or error}") from None
    except ValueError as error:
        raise CliError(str(error)) from None
    try:
        server = ViewServer(args.host, args.port, frames=frames)
    except OSError as error:
        raise CliError(f"cannot serve on {args.host}:{args.port}: {error.strerror or error} (try --port 0)") from None
    except RuntimeError as error:
        raise CliError(str(error)) from None
    url = server.url + (f"?at={args.at:g}" if args.at is not None else "")
    print(f"{args.recording}: {len(frames)} frame(s); open {url} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        server.close()
    return 0

"""The ``d4rt`` command line: a thin layer over the Python API.

Each subcommand lives in its own module with ``register(subparsers)``, which adds its parser and sets
``func``. Errors meant for users are raised as :class:`d4rt.errors.UserError` and printed as one line
(exit status 2); any other exception is a bug, also printed as one line (exit status 1). ``--debug``
(before or after the subcommand) prints the traceback too; ``--no-progress`` turns every progress bar
off; ``--version`` prints the installed version. Only the chosen subcommand's module is imported, so a
bad argument is reported before torch loads.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from d4rt.allocator import reuse_large_buffers
from d4rt.errors import UserError
from d4rt.progress import set_progress

# One module per subcommand (``d4rt.cli.<name>``), in the order `d4rt --help` lists them, with its
# one-line help.
COMMANDS = {"reconstruct": 'reconstruct a video in 4D and write depth, cameras, points, tracks and viewers',
            "stream": 'reconstruct a live video (camera, URL, pipe) window by window as frames arrive',
            "view": "explore a reconstruction in an interactive 3D viewer in the browser (viser)",
            "app": "a local web app: upload a video, get its reconstruction back (gradio)",
            "demo": 'every output on the bundled samples (no arguments needed)',
            "eval": 'evaluate a checkpoint and baselines on a benchmark',
            "generate": 'render synthetic clips with exact ground truth',
            "info": "show a model preset's architecture and parameter counts",
            "train": 'train a model from a YAML config (resumable; runs under torchrun too)',
            "bench": 'measure speed and memory (encoder, decoder, pose FPS, tracks at FPS, dense tracking)'}


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    """The whole parser; given the command line, only the chosen subcommand's module is imported (the
    others are listed by name), so its argument errors come before torch loads."""
    parser = argparse.ArgumentParser(prog="d4rt", description="D4RT: dynamic 4D reconstruction from video.")
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    parser.add_argument("--debug", dest="debug_all", action="store_true", help="show tracebacks of errors")
    parser.add_argument("--no-progress", dest="no_progress_all", action="store_true",
                        help="no progress bars (for logs: bars write carriage returns and escape codes)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    chosen = next((a for a in (argv or []) if not a.startswith("-")), None)
    for name, summary in COMMANDS.items():
        if chosen in COMMANDS and name != chosen:
            sub.add_parser(name, help=summary)
            continue
        importlib.import_module(f"d4rt.cli.{name}").register(sub)
        # Also accepted after the subcommand (their own dests: a subparser's default would overwrite the
        # top-level flag's value).
        sub.choices[name].add_argument("--debug", action="store_true", help="show tracebacks of errors")
        sub.choices[name].add_argument("--no-progress", action="store_true", help="no progress bars")
    return parser


def add_server_arguments(parser, default_port: int) -> None:
    """--host (loopback by default) and --port of the commands that serve a page (view, app)."""
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to serve on (default: 127.0.0.1, this machine only; 0.0.0.0 serves the network)")
    parser.add_argument("--port", type=int, default=default_port, help=f"port to serve on (default: {default_port})")


def check_port(port: int) -> None:
    if not 0 < port < 65536:
        raise UserError(f"--port must be in 1..65535, got {port}")


def parse_size(text: str, option: str) -> tuple[int, int]:
    """The command line's one size syntax: 'WIDTHxHEIGHT' (e.g. 640x480) or 'N' (N x N) -> (height, width);
    a bad value is a UserError naming ``option``."""
    parts = str(text).lower().split("x")
    if len(parts) in (1, 2) and all(p.isdigit() and int(p) > 0 for p in parts):
        width, height = int(parts[0]), int(parts[-1])
        return height, width
    raise UserError(f"{option} must be WIDTHxHEIGHT (e.g. 640x480) or one number for a square, got {text!r}")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("d4rt")
    except PackageNotFoundError:  # pragma: no cover - a source tree that was never installed
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    quiet = args.no_progress or args.no_progress_all
    previous = set_progress(False) if quiet else None
    reuse_large_buffers()  # before the first large allocation: see d4rt.allocator
    try:
        return _run(args, args.debug or args.debug_all)
    finally:
        if quiet:
            set_progress(previous)  # main() may be called again in this process (tests, notebooks)


def _run(args, debug: bool) -> int:
    try:
        return int(args.func(args) or 0)
    except UserError as err:
        if debug:
            traceback.print_exc()
        print(f"d4rt {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"d4rt {args.command}: interrupted", file=sys.stderr)
        return 130
    except Exception as err:  # a bug: one line for users, the traceback with --debug
        if debug:
            traceback.print_exc()
        print(f"d4rt {args.command}: internal error: {type(err).__name__}: {err} "
              "(run again with --debug for the traceback, and please report it)", file=sys.stderr)
        return 1

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

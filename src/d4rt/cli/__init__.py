"""The ``d4rt`` command line: a thin layer over the Python API.

Each subcommand lives in its own module with ``register(subparsers)``, which adds its parser and sets
``func``. Errors meant for users are raised as :class:`d4rt.errors.UserError` and printed as one line
(exit status 2); any other exception is a bug, also printed as one line (exit status 1). ``--debug``
(before or after the subcommand) prints the traceback too.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import traceback

from d4rt.errors import UserError

# One module per subcommand, in the order `d4rt --help` lists them.
COMMANDS = ["reconstruct", "demo", "eval", "generate", "info", "train", "bench"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="d4rt", description="D4RT: dynamic 4D reconstruction from video.")
    parser.add_argument("--debug", dest="debug_all", action="store_true", help="show tracebacks of errors")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"d4rt.cli.{name}").register(sub)
        # Also accepted after the subcommand (its own dest: a subparser's default would overwrite the
        # top-level flag's value).
        sub.choices[name].add_argument("--debug", action="store_true", help="show tracebacks of errors")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    debug = args.debug or args.debug_all
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

"""The ``d4rt`` command line: a thin layer over the Python API.

Each subcommand lives in its own module with ``register(subparsers)``, which adds its parser and sets
``func``. Errors meant for users are raised as :class:`d4rt.errors.UserError` and printed as one line.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from d4rt.errors import UserError

# One module per subcommand, in the order `d4rt --help` lists them.
COMMANDS = ["demo", "eval", "generate", "info", "train"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="d4rt", description="D4RT: dynamic 4D reconstruction from video.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in COMMANDS:
        importlib.import_module(f"d4rt.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except UserError as err:
        print(f"d4rt {args.command}: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"d4rt {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""``d4rt view OUT_DIR``: the interactive viser viewer of a finished reconstruction (d4rt.viz.viser_viewer)."""

from __future__ import annotations

from d4rt.cli import COMMANDS, add_server_arguments, check_port


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view", help=COMMANDS["view"],
        description="Serve an interactive 3D viewer (viser) of what d4rt reconstruct wrote: timeline, points, "
                    "confidence threshold, cameras, tracks. Needs pip install 'd4rt[viewer]'.")
    p.add_argument("folder", metavar="OUT_DIR", help="an output folder of d4rt reconstruct (with reconstruction.npz)")
    add_server_arguments(p, 8080)
    p.set_defaults(func=run)


def run(args) -> int:
    from d4rt.viz.viser_viewer import serve

    check_port(args.port)
    serve(args.folder, host=args.host, port=args.port)
    return 0

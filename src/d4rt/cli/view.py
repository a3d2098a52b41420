"""``d4rt view OUT_DIR``: the interactive viser viewer of a finished reconstruction (d4rt.viz.viser_viewer)."""

from __future__ import annotations

from d4rt.cli import COMMANDS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "view", help=COMMANDS["view"],
        description="Serve an interactive 3D viewer (viser) of what d4rt reconstruct wrote: timeline, points, "
                    "confidence threshold, cameras, tracks. Needs pip install 'd4rt[viewer]'.")
    p.add_argument("folder", metavar="OUT_DIR", help="an output folder of d4rt reconstruct (with reconstruction.npz)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to serve on (default: 127.0.0.1, this machine only; 0.0.0.0 serves the network)")
    p.add_argument("--port", type=int, default=8080, help="port to serve on (default: 8080)")
    p.set_defaults(func=run)


def run(args) -> int:
    from d4rt.errors import UserError
    from d4rt.viz.viser_viewer import serve

    if not 0 < args.port < 65536:
        raise UserError(f"--port must be in 1..65535, got {args.port}")
    serve(args.folder, host=args.host, port=args.port)
    return 0

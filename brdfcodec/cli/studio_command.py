"""``bvae studio [LIB.bvae ...]``: the slider editor and the UMAP manifold explorer in the browser."""

from __future__ import annotations

import argparse
import ipaddress
from pathlib import Path

__all__ = ["register"]


def register(subparsers: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    """Add the ``studio`` sub-command."""
    parser = subparsers.add_parser(
        "studio",
        help="edit materials in the browser: slider editor and UMAP manifold explorer",
        description="Start a local web application with the paper's two interfaces: one slider per latent "
        "parameter with a live sphere preview, and a UMAP map of the library's latents whose cursor is mapped "
        "back to a latent code. Needs the studio extra: pip install \"brdfcodec[studio]\".",
    )
    parser.add_argument("libraries", nargs="*", type=Path, metavar="LIB.bvae",
                        help="libraries to open (default: the shipped 90-material example library)")
    parser.add_argument("--host", default="127.0.0.1",
                        help="address to bind (default 127.0.0.1: this machine only)")
    parser.add_argument("--port", type=int, default=8765, help="port (default 8765; 0 picks a free one)")
    parser.add_argument("--model", help="model folder or decoder SHA-256 (default: the one the libraries name)")
    parser.add_argument("--env", type=Path, metavar="MAP.exr",
                        help="a lat-long EXR offered as environment lighting besides the built-in sky")
    parser.add_argument("--save-dir", type=Path, default=Path("."),
                        help="folder where saved and exported files go (default: the current folder)")
    parser.set_defaults(handler=run)


def _allowed_hosts(host: str) -> list[str] | None:
    """Host headers to serve: localhost names for a loopback bind, anything for a public bind."""
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = host == "localhost"
    return None if loopback else ["*"]


def run(args: argparse.Namespace) -> int:
    """Open the libraries, start the server and print its URL; runs until interrupted."""
    try:
        import uvicorn

        from brdfcodec.studio.server import StudioServer, create_app
    except ImportError as error:
        raise ValueError(f'bvae studio needs the studio extra ({error.name} is missing): '
                         'pip install "brdfcodec[studio]"') from error
    from brdfcodec.studio.catalogue import Catalogue

    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in [0, 65535], got {args.port}")
    catalogue = Catalogue(args.libraries or None, model=args.model)
    server = StudioServer(catalogue, save_dir=args.save_dir, environment=args.env)
    server.start_manifold()  # fit (or load) the UMAP map while the editor is already usable
    app = create_app(server, allowed_hosts=_allowed_hosts(args.host))
    config = uvicorn.Config(app, host=args.host, port=args.port, log_level="warning", access_log=False)

    class AnnouncingServer(uvicorn.Server):
        async def startup(self, sockets: list | None = None) -> None:  # type: ignore[override]
            await super().startup(sockets=sockets)
            bound = [s for srv in getattr(self, "servers", []) for s in srv.sockets]
            port = bound[0].getsockname()[1] if bound else args.port
            shown = f"[{args.host}]" if ":" in args.host else args.host
            print(f"bvae studio: {len(catalogue.materials)} materials; open http://{shown}:{port}/  (Ctrl-C stops)",
                  flush=True)
            if _allowed_hosts(args.host) is not None:
                print(f"bvae studio: warning: bound to {args.host}, reachable from other machines", flush=True)

    AnnouncingServer(config).run()
    return 0

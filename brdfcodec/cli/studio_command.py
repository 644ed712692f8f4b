"""``bvae studio [LIB.bvae ...]``: the slider editor and the UMAP manifold explorer in the browser."""

from __future__ import annotations

import argparse
import ipaddress
import socket
from pathlib import Path

from brdfcodec.cli.usage import UsageError

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
                        help="address to bind (default 127.0.0.1: this machine only). On any other address the "
                        "studio answers only requests whose Host header names that address, this machine's host "
                        "names or localhost (no DNS rebinding); --allow-host adds names")
    parser.add_argument("--allow-host", action="append", default=[], metavar="NAME",
                        help="a further Host header name to answer (a proxy's or an alias's; repeatable; "
                        "'*' answers any, which lets any web page the user visits drive the studio)")
    parser.add_argument("--port", type=int, default=8765, help="port (default 8765; 0 picks a free one)")
    parser.add_argument("--model", help="model folder, model name or decoder SHA-256 (default: the one the "
                        "libraries name)")
    parser.add_argument("--env", type=Path, metavar="MAP.exr",
                        help="a lat-long EXR offered as environment lighting besides the built-in sky")
    parser.add_argument("--save-dir", type=Path, default=None,
                        help="folder where saved and exported files go (default: the current folder on "
                        "127.0.0.1 or localhost; on any other address saving is off unless this is given, since "
                        "other machines could then write there)")
    parser.set_defaults(handler=run)


_LOCAL_NAMES = ["127.0.0.1", "localhost", "::1", "[::1]"]


def _is_loopback(host: str) -> bool:
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return host == "localhost"


def _machine_names() -> list[str]:
    """This machine's host name, fully qualified name and their addresses (what other machines may call it)."""
    names: list[str] = []
    for name in {socket.gethostname(), socket.getfqdn()}:
        if name:
            names.append(name)
            try:
                names.extend(socket.gethostbyname_ex(name)[2])
            except OSError:
                pass
    return names


def _allowed_hosts(host: str, extra: list[str] | None = None) -> list[str] | None:
    """Host headers to serve: localhost names for a loopback bind (``None``: the application's default); for a
    public bind, the bound address, this machine's names and addresses, localhost names and ``extra``. Never
    ``*`` unless ``extra`` says so (a ``*`` would let a web page re-bound to this address by DNS drive the
    studio)."""
    if _is_loopback(host) and not extra:
        return None
    names = [*_LOCAL_NAMES, *(extra or [])]
    if not _is_loopback(host):
        unspecified = host in ("0.0.0.0", "::", "")
        names += ([] if unspecified else [host, f"[{host}]" if ":" in host else host]) + _machine_names()
    return list(dict.fromkeys(names))


def _save_dir(args: argparse.Namespace) -> Path | None:
    """The save folder: ``--save-dir``; else the current folder on a loopback bind, none (saving off) otherwise."""
    if args.save_dir is not None:
        return args.save_dir
    return Path(".") if _is_loopback(args.host) else None


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
    from brdfcodec.studio.http_guard import server_config

    for name in args.allow_host:
        if not name or any(c.isspace() or c in "/@" for c in name):
            raise UsageError(f"--allow-host: {name!r} is not a host name")
    catalogue = Catalogue(args.libraries or None, model=args.model)
    server = StudioServer(catalogue, save_dir=_save_dir(args), environment=args.env)
    server.start_manifold()  # fit (or load) the UMAP map while the editor is already usable
    hosts = _allowed_hosts(args.host, args.allow_host)
    app = create_app(server, allowed_hosts=hosts)
    config = server_config(app, host=args.host, port=args.port)

    class AnnouncingServer(uvicorn.Server):
        async def startup(self, sockets: list | None = None) -> None:  # type: ignore[override]
            await super().startup(sockets=sockets)
            bound = [s for srv in getattr(self, "servers", []) for s in srv.sockets]
            port = bound[0].getsockname()[1] if bound else args.port
            shown = f"[{args.host}]" if ":" in args.host else args.host
            print(f"bvae studio: {_materials_line(catalogue)}; open http://{shown}:{port}/  (Ctrl-C stops)",
                  flush=True)
            saving = (f"saving to {server.save_dir}" if server.save_dir is not None
                      else "saving is off (give --save-dir FOLDER to save)")
            print(f"bvae studio: {saving}", flush=True)
            if not _is_loopback(args.host):
                answered = "any Host header ('*')" if hosts and "*" in hosts else (
                    f"Host headers {', '.join(hosts or _LOCAL_NAMES)}")
                print(f"bvae studio: warning: bound to {args.host}, reachable from other machines, which can "
                      f"edit and {'save' if server.save_dir is not None else 'view'} materials; answering "
                      f"{answered} (--allow-host adds names)", flush=True)

    AnnouncingServer(config).run()
    return 0


def _materials_line(catalogue: object) -> str:
    """``90 materials`` or ``90 of 93 materials (3 left out: no latent code to edit …)`` (issue 52)."""
    shown = len(catalogue.materials)  # type: ignore[attr-defined]
    left_out = len(catalogue.without_latent)  # type: ignore[attr-defined]
    if not left_out:
        return f"{shown} materials"
    return (f"{shown} of {shown + left_out} materials ({left_out} left out: basis-only records, no latent code to "
            "edit; re-encode them with `bvae compress --latent always` to edit them)")

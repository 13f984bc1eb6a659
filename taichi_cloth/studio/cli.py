"""`python -m taichi_cloth studio [GARMENT.toml | PATTERN.dxf | SPECIFICATION.json]`: serve the pattern studio's
page from the current folder (docs/studio.md). The server's packages are the `studio` extra; without them the
command says so in one line."""
from __future__ import annotations

import socket
import sys
import threading
import webbrowser
from pathlib import Path

from .folder import OPENS, Folder, Refused

DEFAULT_PORT = 8765
EXTRA = "pip install -e '.[studio]'"


def add_parser(sub) -> None:
    p = sub.add_parser("studio", help="the pattern studio: a local web page to sew and place a garment's pieces, "
                       "save its garment file and drape it")
    p.add_argument("file", nargs="?", help="a DXF pattern, a garment file (.toml) or a GarmentCode "
                   "specification (.json) in this folder to open")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"port (default {DEFAULT_PORT})")
    p.add_argument("--no-browser", action="store_true", help="do not open a browser on the page")
    p.set_defaults(func=run)


def _say(line: str) -> int:
    print(line, file=sys.stderr)
    return 2


def run(args) -> int:
    try:
        import multipart  # noqa: F401  (python-multipart: the page's uploads)
        import starlette  # noqa: F401
        import uvicorn
    except ImportError as exc:
        return _say(f"error: the pattern studio needs {exc.name}, which is not installed: {EXTRA}")
    from .server import create_app  # starlette's: the studio extra

    root = Path.cwd()
    start = None
    if args.file:
        folder = Folder(root)
        try:  # the studio reads only under its folder: the file must be in it
            start = folder.relative(folder.resolve(args.file, OPENS, must_exist=True))
        except Refused as exc:
            return _say(f"error: {exc}")
    with socket.socket() as probe:  # a port in use is one line, not a server's traceback
        try:
            probe.bind((args.host, args.port))
        except OSError as exc:
            return _say(f"error: cannot listen on {args.host}:{args.port}: {exc.strerror or exc}; pass --port")
    app = create_app(root, start)  # a broken start file: one `error:` line (taichi_cloth.cli.ends)
    host = f"[{args.host}]" if ":" in args.host else args.host
    url = f"http://{host}:{args.port}/"
    print(f"pattern studio: {url}  (folder {root}; Ctrl-C stops it)", flush=True)
    if not args.no_browser:
        threading.Timer(1.0, webbrowser.open, [url]).start()
    uvicorn.run(app, host=args.host, port=args.port, log_level="warning")
    return 0

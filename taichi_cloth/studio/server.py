"""The studio's HTTP side (Starlette): the page and its files, and a JSON route per operation of the session.

Every route that changes the set-up answers with the whole state ({"state": ...}) so the page redraws from one
answer; a refusal answers {"error": "<one line>"} with its status (400 bad input, 403 a path leading outside the
folder, 404 missing, 409 not now, 413 an upload over MAX_UPLOAD) and changes nothing. docs/studio.md lists the routes.
"""
from __future__ import annotations

import contextlib
import json
from pathlib import Path

from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from ..errors import MeshError, TaichiClothError
from ..garment.pattern import unit_scale
from ..paths import os_error_text
from . import views
from .drape import DEFAULT_FRAMES, MAX_FRAMES, QUICK_SPACING, DrapeJob, run_command, write_drape
from .folder import Folder, Refused
from .session import Session

STATIC = Path(__file__).resolve().parent / "static"
#: [bytes] the largest file the page may upload
MAX_UPLOAD = 5 * 1024 * 1024
#: [bytes] room for the multipart framing around an upload
_FRAMING = 64 * 1024


def error(message: str, status: int = 400) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


class Studio:
    """The studio behind the routes: the folder, the session, the drape job and the last placement picture.

    drape_command(scene, out, frames) -> argv: what a drape runs (default drape.run_command; the tests give a
    quick stand-in)."""

    def __init__(self, root, start: str | None = None, drape_command=None, anchors=None):
        self.folder = Folder(root)
        self.session = Session(self.folder, anchors if anchors is not None else views.anchors())
        self.job = DrapeJob(self.folder.root)
        self.drape_command = drape_command or run_command
        self._picture = (None, None)
        self.session.find_autosave()
        if start:
            self.session.open(start)

    def state(self) -> dict:
        out = self.session.state()
        out["drape"] = self.job.status()
        return out

    def picture(self) -> bytes:
        with self.session.lock:
            version, spec = self.session.version, self.session.spec
        if spec is None:
            raise Refused("no pattern open", 409)
        if self._picture[0] != version:
            self._picture = (version, views.placement_picture(spec))
        return self._picture[1]

    def drape(self, frames, quick: bool, spacing) -> dict:
        if self.job.running:
            raise Refused("a drape is running: wait for it or stop it", 409)
        if isinstance(frames, bool) or not isinstance(frames, int) or not 1 <= frames <= MAX_FRAMES:
            raise Refused(f"frames must be a whole number in 1..{MAX_FRAMES}, got {frames!r}", 400)
        with self.session.lock:
            if self.session.spec is None:
                raise Refused("no pattern open: nothing to drape", 409)

            scale = unit_scale(self.session.doc.get("units", "m"))
            coarse = None
            if quick:
                if spacing is None:
                    coarse = max(QUICK_SPACING, self.session.spec.spacing)
                elif isinstance(spacing, (int, float)) and not isinstance(spacing, bool) and spacing > 0:
                    coarse = float(spacing) * scale
                else:
                    raise Refused(f"the quick drape's spacing must be a length > 0, got {spacing!r}", 400)
            scene, out = write_drape(self.session, frames, coarse)
        used = coarse or self.session.spec.spacing
        self.job.start(self.drape_command(scene, out, frames), out, frames,
                       ("quick, " if quick else "") + f"spacing {used / scale:g} {self.session.doc.get('units', 'm')}")
        return self.job.status()


#: [bytes] the largest JSON body a route reads (an edit is a few hundred bytes)
MAX_JSON = 1024 * 1024


async def _json(request: Request) -> dict:
    size = request.headers.get("content-length")
    if size is not None and size.isdigit() and int(size) > MAX_JSON:
        raise Refused(f"the request is larger than the {MAX_JSON // 1024} KB an edit may be", 413)
    try:
        data = await request.json()
    except (json.JSONDecodeError, UnicodeDecodeError):
        raise Refused("the request's body is not JSON", 400) from None
    if not isinstance(data, dict):
        raise Refused("the request's body must be a JSON object", 400)
    return data


def create_app(root, start: str | None = None, drape_command=None, anchors=None) -> Starlette:
    """The studio's app for the start folder `root`, with `start` (a DXF or garment file in it) open."""
    studio = Studio(root, start, drape_command, anchors)

    async def call(fn, *args, **kwargs) -> Response:
        """Run a session operation off the event loop; its refusal becomes {"error"} with a status."""
        try:
            result = await run_in_threadpool(fn, *args, **kwargs)
        except Refused as exc:
            return error(str(exc), exc.status)
        except (TaichiClothError, MeshError, ValueError) as exc:
            return error(studio.session.short(exc), 400)
        except OSError as exc:  # a file that cannot be read or written: its path (in the folder) and why
            return error(studio.session.short(os_error_text(exc)), 400)
        except Exception as exc:  # the page must go on working: one line, the set-up untouched
            return error(f"unexpected {type(exc).__name__}: {exc}", 500)
        body = {"state": await run_in_threadpool(studio.state)}
        if isinstance(result, dict):
            body.update(result)
        return JSONResponse(body)

    def guarded(handler):
        async def endpoint(request: Request) -> Response:
            try:
                return await handler(request)
            except Refused as exc:
                return error(str(exc), exc.status)
        return endpoint

    async def index(request):
        return FileResponse(STATIC / "index.html")

    async def state(request):
        return JSONResponse(await run_in_threadpool(studio.state))

    async def files(request):
        return JSONResponse({"files": await run_in_threadpool(studio.folder.files)})

    async def open_file(request):
        data = await _json(request)
        return await call(studio.session.open, data.get("path"), data.get("units") or None)

    async def upload(request):
        size = request.headers.get("content-length")
        if size is not None and size.isdigit() and int(size) > MAX_UPLOAD + _FRAMING:
            return error(f"the file is larger than the {MAX_UPLOAD // 2 ** 20} MB the studio takes", 413)
        body = bytearray()
        async for chunk in request.stream():
            body += chunk
            if len(body) > MAX_UPLOAD + _FRAMING:
                return error(f"the file is larger than the {MAX_UPLOAD // 2 ** 20} MB the studio takes", 413)
        sent = False

        async def replay():
            nonlocal sent
            if sent:
                return {"type": "http.disconnect"}
            sent = True
            return {"type": "http.request", "body": bytes(body), "more_body": False}

        try:
            form = await Request(request.scope, replay).form(max_files=1, max_fields=4, max_part_size=MAX_UPLOAD)
        except Exception as exc:  # a body that is not multipart form data
            return error(f"the upload is not a file form ({exc})", 400)
        item = form.get("file")
        if item is None or not hasattr(item, "read"):
            return error("the upload has no file (a form field named 'file')", 400)
        data = await item.read()
        if len(data) > MAX_UPLOAD:
            return error(f"the file is larger than the {MAX_UPLOAD // 2 ** 20} MB the studio takes", 413)
        kept = []

        def open_upload():
            units = form.get("units")
            kept.append(studio.session.open_upload(item.filename or "", data, units if isinstance(units, str) and units
                                                   else None))
            return {"kept": kept[0]}

        return await call(open_upload)

    async def set_name(request):
        data = await _json(request)
        return await call(studio.session.set_name, data.get("name"))

    async def add_seam(request):
        data = await _json(request)

        def add():
            return {"index": studio.session.add_seam(data.get("a"), data.get("b"), data.get("name"),
                                                     data.get("tolerance"))}

        return await call(add)

    async def edit_seam(request):
        data = await _json(request)
        return await call(studio.session.edit_seam, request.path_params["index"], data.get("name"),
                          data.get("tolerance"))

    async def flip_seam(request):
        data = await _json(request)
        return await call(studio.session.flip_seam, request.path_params["index"], data.get("side"))

    async def delete_seam(request):
        return await call(studio.session.delete_seam, request.path_params["index"])

    async def place(request):
        data = await _json(request)
        return await call(studio.session.set_placement, request.path_params["piece"], data)

    async def piece_pattern(request):
        data = await _json(request)
        return await call(studio.session.set_piece_pattern, request.path_params["piece"], data)

    async def dxf_options(request):
        data = await _json(request)
        return await call(studio.session.set_dxf_options, data)

    async def material(request):
        data = await _json(request)
        return await call(studio.session.set_material, data.get("preset"), data.get("values"))

    async def spacing(request):
        data = await _json(request)
        return await call(studio.session.set_spacing, data.get("spacing"))

    async def undo(request):
        return await call(studio.session.undo)

    async def redo(request):
        return await call(studio.session.redo)

    async def save(request):
        data = await _json(request)

        def save_it():
            return {"saved": studio.session.save(data.get("path"), bool(data.get("overwrite", False)))}

        return await call(save_it)

    async def restore(request):
        return await call(studio.session.restore)

    async def dismiss(request):
        return await call(studio.session.dismiss_restore)

    async def picture(request):
        try:
            png = await run_in_threadpool(studio.picture)
        except Refused as exc:
            return error(str(exc), exc.status)
        except (TaichiClothError, MeshError, ValueError) as exc:
            return error(studio.session.short(exc), 400)
        return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})

    async def drape_start(request):
        data = await _json(request)
        def drape():
            return {"drape": studio.drape(data.get("frames", DEFAULT_FRAMES), bool(data.get("quick", True)),
                                          data.get("spacing"))}

        return await call(drape)

    async def drape_status(request):
        return JSONResponse(studio.job.status())

    async def drape_cancel(request):
        return JSONResponse({"cancelled": studio.job.cancel(), **studio.job.status()})

    async def folder_file(request):
        """A picture from the folder (a drape's stills): only .png, only under the folder."""
        path = studio.folder.resolve(request.path_params["path"], suffixes=(".png",), must_exist=True)
        return FileResponse(path, headers={"Cache-Control": "no-store"})

    routes = [
        Route("/", index),
        Route("/api/state", state),
        Route("/api/files", files),
        Route("/api/open", guarded(open_file), methods=["POST"]),
        Route("/api/upload", guarded(upload), methods=["POST"]),
        Route("/api/name", guarded(set_name), methods=["POST"]),
        Route("/api/seams", guarded(add_seam), methods=["POST"]),
        Route("/api/seams/{index:int}", guarded(edit_seam), methods=["PATCH"]),
        Route("/api/seams/{index:int}", guarded(delete_seam), methods=["DELETE"]),
        Route("/api/seams/{index:int}/flip", guarded(flip_seam), methods=["POST"]),
        Route("/api/placements/{piece}", guarded(place), methods=["PUT"]),
        Route("/api/pieces/{piece}/pattern", guarded(piece_pattern), methods=["PUT"]),
        Route("/api/dxf", guarded(dxf_options), methods=["PUT"]),
        Route("/api/material", guarded(material), methods=["PUT"]),
        Route("/api/spacing", guarded(spacing), methods=["PUT"]),
        Route("/api/undo", guarded(undo), methods=["POST"]),
        Route("/api/redo", guarded(redo), methods=["POST"]),
        Route("/api/save", guarded(save), methods=["POST"]),
        Route("/api/restore", guarded(restore), methods=["POST"]),
        Route("/api/restore/dismiss", guarded(dismiss), methods=["POST"]),
        Route("/api/views/placement.png", picture),
        Route("/api/drape", guarded(drape_start), methods=["POST"]),
        Route("/api/drape", drape_status),
        Route("/api/drape/cancel", drape_cancel, methods=["POST"]),
        Route("/files/{path:path}", guarded(folder_file)),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    @contextlib.asynccontextmanager
    async def lifespan(app):
        yield
        studio.job.stop()  # a drape still running ends with the studio

    app = Starlette(routes=routes, lifespan=lifespan)
    app.state.studio = studio
    return app

"""The operator console: the static files ``web/`` builds into ``web/dist`` (``npm ci &&
npm run build``, which ``scripts/setup.sh`` runs), served at ``/``; an installed wheel
carries them as package data (setup.py).

``/`` (and ``/index.html``) is the console's page; ``/assets/...`` its content-hashed
bundles (cached for good); ``/model/...`` the model files the setup script exports next to
it. ``/docs`` is the API's documentation page, Swagger UI served from the same build
(``/swagger/...``: ``swagger-ui-dist``, pinned in web/package.json), never from a CDN, so it
works offline as the rest does; without a build it answers 503 and points to
``/openapi.json``. Without a build, ``/`` answers 503 with a page that says how to build it, so an
operator never mistakes a missing console for a dead server. Nothing here is under
``/api`` and nothing is in the OpenAPI document. The pages' Content-Security-Policy and the
other security headers are the edge's (server/api/edge.py, docs/security.md).
"""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import FileResponse, HTMLResponse, Response

from server.api.errors import HttpError

__all__ = ["DEFAULT_DIST", "make_router"]

#: The console's build: in an installed wheel beside this module (``console``, setup.py
#: copies ``web/dist`` there), else ``web/dist`` of the checkout (an editable install).
_PACKAGED = Path(__file__).resolve().parent / "console"
DEFAULT_DIST = (
    _PACKAGED if _PACKAGED.is_dir() else Path(__file__).resolve().parents[2] / "web" / "dist"
)

_NOT_BUILT = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Hikoboshi: console not built</title>
<style>body{{background:#0d1017;color:#e6e9ef;font:15px/1.5 system-ui,sans-serif;
margin:10vh auto;max-width:640px}}code,pre{{background:#151a23;padding:2px 6px}}</style>
</head><body><h1>The operator console is not built</h1>
<p>The ground service is running (the API is at <a href="/docs" style="color:#4fc3f7">/docs</a>),
but there is no console in <code>{dist}</code>.</p>
<p>Build it (Node.js 22 or 24 LTS and npm), then reload this page:</p>
<pre>bash scripts/setup.sh          # or: cd web &amp;&amp; npm ci &amp;&amp; npm run build</pre>
</body></html>
"""

#: Content types of the files a build holds (the console's own, nothing else is served).
_TYPES = {
    ".js": "text/javascript",
    ".css": "text/css",
    ".map": "application/json",
    ".txt": "text/plain",
    ".urdf": "application/xml",
    ".png": "image/png",
}

_DOCS_NOT_BUILT = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>Hikoboshi: API docs not built</title>
</head><body><h1>The API's documentation page is not built</h1>
<p>Its Swagger UI comes with the console's build, which is missing in <code>{dist}</code>
(<code>bash scripts/setup.sh</code>). The API's description is at
<a href="/openapi.json">/openapi.json</a>.</p></body></html>
"""


def _file(root: Path, name: str, cache: str) -> Response:
    """``root/name`` if it is a file of a known type inside ``root``, else 404 (a name with
    a control character too: the edge refuses those first, and the file system would raise
    on a NUL)."""
    if not name.isprintable():
        raise HttpError(404, "not_found", f"no console file {name!r}")
    path = (root / name).resolve()
    if not path.is_relative_to(root.resolve()) or not path.is_file() or path.suffix not in _TYPES:
        raise HttpError(404, "not_found", f"no console file {name!r}")
    return FileResponse(path, media_type=_TYPES[path.suffix], headers={"Cache-Control": cache})


def make_router(dist: Path = DEFAULT_DIST) -> APIRouter:
    """Routes serving the console built in ``dist``."""
    router = APIRouter(include_in_schema=False)

    @router.get("/")
    @router.get("/index.html")
    def index() -> Response:
        page = dist / "index.html"
        if not page.is_file():
            return HTMLResponse(_NOT_BUILT.format(dist=dist), status_code=503)
        # Always revalidated: it names the current bundles.
        return FileResponse(page, media_type="text/html", headers={"Cache-Control": "no-cache"})

    @router.get("/assets/{name}")
    def asset(name: str) -> Response:
        # Names carry a content hash: a file never changes under its name.
        return _file(dist / "assets", name, "public, max-age=31536000, immutable")

    @router.get("/model/{name}")
    def model(name: str) -> Response:
        return _file(dist / "model", name, "no-cache")

    @router.get("/docs")
    def docs() -> Response:
        if not (dist / "swagger" / "swagger-ui-bundle.js").is_file():
            return HTMLResponse(_DOCS_NOT_BUILT.format(dist=dist), status_code=503)
        return get_swagger_ui_html(
            openapi_url="/openapi.json",
            title="Hikoboshi ground service: API",
            swagger_js_url="/swagger/swagger-ui-bundle.js",
            swagger_css_url="/swagger/swagger-ui.css",
            swagger_favicon_url="/swagger/favicon-32x32.png",
        )

    @router.get("/swagger/{name}")
    def swagger(name: str) -> Response:
        # Named by the pinned package, not by content: revalidated.
        return _file(dist / "swagger", name, "no-cache")

    return router

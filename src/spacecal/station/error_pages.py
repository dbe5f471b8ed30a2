"""Every answer the station gives when it cannot do what was asked: a page in the station's
style with one line saying why, and the status that says what kind of failure it was.

Nothing a person meets at the station is a bare text, an unstyled 403 or a traceback: a refused
request (:func:`refuse`, the doors of :mod:`spacecal.station.access`), an unknown calibration
or file (404), a record that cannot be written (503, in the record's own words), and anything
unforeseen (500) all come here.
"""

from __future__ import annotations

from http import HTTPStatus
from pathlib import Path
from typing import Any

from jinja2 import Environment, FileSystemLoader, select_autoescape
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import HTMLResponse, Response

from spacecal.core.errors import RecordError
from spacecal.core.text import exception_line, sanitize_for_terminal

_templates = Environment(
    loader=FileSystemLoader(str(Path(__file__).resolve().parent / "templates")),
    autoescape=select_autoescape(default=True),
)
#: Longest line of an error page, characters (a message may quote an input).
LINE_LIMIT = 400


def error_body(status: int, text: str) -> bytes:
    """The page for ``status`` with the one line ``text`` (shown as text, bounded)."""
    try:
        title = HTTPStatus(status).phrase
    except ValueError:
        title = "Error"
    line = sanitize_for_terminal(" ".join(str(text).split()), LINE_LIMIT)
    page = _templates.get_template("error.html").render(title=title, text=line, sign_in=status == 401)
    return page.encode("utf-8")


def error_page(status: int, text: str) -> Response:
    """:func:`error_body` as a response, never cached."""
    return HTMLResponse(error_body(status, text), status_code=status, headers={"Cache-Control": "no-store"})


async def refuse(scope: dict[str, Any], receive: Any, send: Any, status: int, text: str) -> None:
    """Answer a request the station's doors refused: a websocket is closed (policy violation,
    1008) before it is accepted; a page request gets the error page."""
    if scope["type"] == "websocket":
        await receive()  # the connect event
        await send({"type": "websocket.close", "code": 1008, "reason": text[:120]})
        return
    body = error_body(status, text)
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"text/html; charset=utf-8"),
                (b"content-length", str(len(body)).encode()),
                (b"cache-control", b"no-store"),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})


async def _http_error(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, HTTPException)
    words = {404: "nothing at this address", 405: "this address does not take that request"}
    return error_page(exc.status_code, words.get(exc.status_code, exc.detail))


async def _not_found(request: Request, exc: Exception) -> Response:
    return error_page(404, exception_line(exc).strip("'\""))


async def _record_unavailable(request: Request, exc: Exception) -> Response:
    return error_page(503, exception_line(exc))


async def _internal(request: Request, exc: Exception) -> Response:
    return error_page(500, f"the station could not do this: {exception_line(exc)}")


#: Starlette's exception handlers of the station (``Starlette(exception_handlers=...)``).
EXCEPTION_HANDLERS: dict[Any, Any] = {
    HTTPException: _http_error,
    LookupError: _not_found,
    RecordError: _record_unavailable,
    Exception: _internal,
}

"""Who may talk to the station, and from which page: the station's doors.

The station moves a robot, so what it must refuse is a request the operator did not make
at the station's own page. Three doors, checked on every request and websocket:

* **The interface.** :func:`check_bind` refuses to listen off loopback without an access
  token. On loopback a request under another host name (a site that rebinds its name to
  127.0.0.1) is refused (421).
* **The token** (:class:`AccessMiddleware`), when one is set (off loopback always; on a shared
  loopback PC by choice): every request carries it in the ``X-Station-Token`` header, or the
  cookie of a session the sign-in page or the printed address opened. A token in the address
  is swapped for that cookie at once and the address bar is cleaned
  (:func:`token_handover_page`). The cookie holds a random session key, never the token:
  cookies are not bound to a port, so a browser sends it to every web server of the station's
  host whose page it opens, and the token must not go with it.
* **The page's origin** (:func:`foreign_request`): a form, a request that changes anything,
  and every websocket must come from a page of the station's own origin (scheme, host and
  port). ``Origin: null`` (a sandboxed frame, a ``data:`` page) is foreign; so is another port
  of the same host (same-site is not same-origin). Where the browser says where a request
  comes from (``Sec-Fetch-Site``), anything but ``same-origin`` or ``none`` (an address the
  user typed) is refused, except a plain link to a page that starts nothing. No page may
  frame the station (:data:`PAGE_SECURITY_HEADERS`).

What the doors cannot do: on loopback without a token, any program of any user of this
computer can speak to the station as its page does (a browser sends ``Origin`` and
``Sec-Fetch-Site``, but a program writes whatever it likes). On a shared station PC, give
the station a token (``--token-file``, readable only by its operator, or
``SPACECAL_STATION_TOKEN``).
"""

from __future__ import annotations

import hmac
import ipaddress
import os
import secrets
import stat
from collections.abc import Mapping
from pathlib import Path
from typing import Any
from urllib.parse import parse_qs, urlencode, urlsplit

from spacecal.core.errors import InvalidInputError

#: The cookie a browser keeps its session key in, with the station's port in its name: cookies
#: are not bound to a port, so two stations on one computer would otherwise overwrite each
#: other's.
TOKEN_COOKIE = "spacecal_station_token"
#: Sessions a station keeps open (one per sign-in; the oldest is closed beyond this): a person
#: signs in once per browser.
MAX_SESSIONS = 64
#: The environment variable a token may be given in (never only on the command line, where
#: every user of the computer reads it in the process list).
TOKEN_ENVIRONMENT = "SPACECAL_STATION_TOKEN"
#: The shortest token accepted, characters.
TOKEN_MIN_LENGTH = 16
#: The longest, characters (a token file is read only this far).
TOKEN_MAX_LENGTH = 256
#: The names the station answers to on loopback.
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1", "[::1]")
#: Methods that change nothing (every other one, and every websocket, must be same-origin).
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
#: What ``Sec-Fetch-Site`` may say of a request that starts, changes or watches anything.
OWN_SITES = ("same-origin", "none")
#: Paths a page of another site may link to (a top-level navigation, never a frame): the pages
#: that start nothing. A confirmation page issues a motion's ticket, so it is not among them.
LINKABLE = ("/", "/trends")
#: The sign-in path (its form is same-origin like any other).
SIGN_IN_PATH = "/sign-in"
#: The largest request body read, bytes: the station's forms are a few hundred bytes.
MAX_BODY_BYTES = 64 * 1024

#: The content security policy of the station's pages: its own scripts and styles only (plotly
#: is served from the station itself), no frame of the station anywhere (clickjacking), forms
#: and connections to itself only. No inline script and no ``eval``: every page script is a
#: file of the station (plotly's 3-D and 2-D figures were seen to draw without either, in
#: Chromium). plotly.js sets inline styles, hence ``'unsafe-inline'`` for styles only.
PAGE_POLICY = "; ".join(
    (
        "default-src 'self'",
        "script-src 'self'",
        "style-src 'self' 'unsafe-inline'",
        "img-src 'self' data: blob:",
        "connect-src 'self'",
        "worker-src 'self' blob:",
        "object-src 'none'",
        "base-uri 'none'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    )
)
#: Every response's headers (a file of a calibration's folder sets its own policy, stricter:
#: :data:`FILE_POLICY`).
PAGE_SECURITY_HEADERS = (
    ("content-security-policy", PAGE_POLICY),
    ("x-frame-options", "DENY"),
    ("x-content-type-options", "nosniff"),
    ("referrer-policy", "same-origin"),  # "no-referrer" makes a browser send "Origin: null"
    ("cross-origin-opener-policy", "same-origin"),
    ("cross-origin-resource-policy", "same-origin"),
)
#: A file of a calibration's folder (a report, an export): in a sandbox of its own origin, so a
#: script in it (the report's plotly figures) can never act as the station's page; no frame.
FILE_POLICY = (
    "sandbox allow-scripts allow-downloads; default-src 'none'; script-src 'unsafe-inline' 'unsafe-eval'; "
    "style-src 'unsafe-inline'; img-src data: blob:; font-src data:; frame-ancestors 'none'"
)


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses."""
    if host.strip("[]").lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_token(token: str) -> str:
    """``token`` when it is usable as the station's access token.

    Raises
    ------
    InvalidInputError
        Shorter than :data:`TOKEN_MIN_LENGTH`, longer than :data:`TOKEN_MAX_LENGTH`, or holding
        anything but printable ASCII without spaces (it travels in a cookie and a header).
    """
    if not TOKEN_MIN_LENGTH <= len(token) <= TOKEN_MAX_LENGTH:
        raise InvalidInputError(
            f"the station's access token must be {TOKEN_MIN_LENGTH} to {TOKEN_MAX_LENGTH} characters"
        )
    if not all("!" <= c <= "~" and c not in ';,"\\' for c in token):
        raise InvalidInputError(
            "the station's access token may hold only printable ASCII without spaces, ';', ',', '\"' or '\\'"
        )
    return token


def check_bind(host: str, token: str | None) -> None:
    """Refuse to listen off loopback without a token.

    Raises
    ------
    InvalidInputError
        ``host`` is not a loopback interface and no token was given, or the token is unusable.
    """
    if token is not None:
        check_token(token)
    if not is_loopback(host) and not token:
        raise InvalidInputError(
            f"the station listens on {host} only with an access token (--token-file FILE or "
            f"{TOKEN_ENVIRONMENT}): anyone who can reach that interface could otherwise move the robot"
        )


def load_token(token_file: str | None, environment: Mapping[str, str] = os.environ) -> str | None:
    """The station's access token: from ``token_file``, else from :data:`TOKEN_ENVIRONMENT`,
    else none.

    A token file that does not exist yet is created with a fresh random token, readable and
    writable by its owner only, so ``--token-file ~/.spacecal-token`` is all a shared station PC
    needs. An existing file readable by other users is refused: they could move the robot.

    Raises
    ------
    InvalidInputError
        The file is readable by others, unreadable, or its first line is not a usable token.
    """
    if token_file is None:
        given = environment.get(TOKEN_ENVIRONMENT)
        return check_token(given.strip()) if given is not None else None
    path = Path(token_file).expanduser()
    if not path.exists():
        token = secrets.token_urlsafe(32)
        try:
            descriptor = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        except OSError as exc:
            raise InvalidInputError(f"cannot create the token file {path}: {exc.strerror}") from exc
        with os.fdopen(descriptor, "w") as out:
            out.write(token + "\n")
        return token
    try:
        mode = path.stat().st_mode
        if not stat.S_ISREG(mode):
            raise InvalidInputError(f"the token file {path} is not a regular file")
        if mode & (stat.S_IRWXG | stat.S_IRWXO):
            raise InvalidInputError(
                f"the token file {path} may be read by other users: chmod 600 {path} "
                "(they could move the robot)"
            )
        with path.open("rb") as source:
            first = source.read(TOKEN_MAX_LENGTH + 2).decode("ascii").splitlines()
    except UnicodeDecodeError as exc:
        raise InvalidInputError(f"the token file {path} holds no ASCII token") from exc
    except OSError as exc:
        raise InvalidInputError(f"cannot read the token file {path}: {exc.strerror}") from exc
    return check_token(first[0].strip() if first else "")


def station_origin(scope: Mapping[str, Any], host: str) -> str:
    """The station's own origin as a page of it sends it: ``http://HOST[:PORT]``."""
    scheme = {"ws": "http", "wss": "https"}.get(scope.get("scheme", "http"), scope.get("scheme", "http"))
    return f"{scheme}://{host}".lower()


def foreign_request(scope: Mapping[str, Any], headers: Mapping[str, str], host: str) -> str | None:
    """Why a request did not come from the station's own page, or None when it may have.

    Parameters
    ----------
    scope : ASGI scope
    headers : mapping
        The request's headers, names in lower case.
    host : str
        The request's ``Host`` header (what the station answers as).

    Returns
    -------
    str or None
        The refusal's reason, or None. A request with neither ``Origin`` nor ``Sec-Fetch-*``
        headers comes from a program, not a browser's page; it passes here (only the token
        keeps programs out).
    """
    websocket = scope["type"] == "websocket"
    method = scope.get("method", "GET")
    unsafe = websocket or method not in SAFE_METHODS
    origin = headers.get("origin")
    site = headers.get("sec-fetch-site")
    if unsafe:
        if origin is not None and origin.lower() != station_origin(scope, host):
            return "a request from another site's page (or a sandboxed frame) is refused"
        if origin is None and (websocket or site is not None):
            return "a browser's request without its page's origin is refused"
    if site is not None and site not in OWN_SITES:
        link = (
            not unsafe
            and headers.get("sec-fetch-mode") == "navigate"
            and headers.get("sec-fetch-dest") == "document"
            and scope.get("path") in LINKABLE
        )
        if not link:
            return "a request from another site's page is refused (open the station's address yourself)"
    return None


def token_handover_page(clean_url: str) -> bytes:
    """The page that answers an address carrying the token: it sets the cookie (in its headers)
    and goes on to ``clean_url`` at once, so the token leaves the address bar. A page of the
    station's own makes that second request, so the cookie goes with it even when the first came
    from a link elsewhere (a strict cookie is not sent on another site's navigation)."""
    from html import escape

    target = escape(clean_url, quote=True)
    return (
        '<!DOCTYPE html><html lang="en"><head><meta charset="utf-8">'
        f'<meta http-equiv="refresh" content="0; url={target}"><title>spacecal station</title></head>'
        f'<body><p>Signed in. <a href="{target}">Open the station</a>.</p></body></html>'
    ).encode()


class AccessMiddleware:
    """ASGI middleware that lets through only the requests the station should answer, and adds
    the station's security headers to every response.

    Parameters
    ----------
    app : ASGI application
    token : str or None
        Required on every request when given: in header ``X-Station-Token``, or as the cookie
        of a session opened by signing in with it (``?token=`` is swapped for that cookie).
        Sessions live as long as the station's process: after a restart, sign in again.
    loopback_only : bool
        Also refuse a ``Host`` header that does not name loopback.
    refuse : callable
        ``refuse(scope, receive, send, status, text)``: answers a refused request (a styled
        page, or a websocket close).
    """

    def __init__(self, app: Any, token: str | None, loopback_only: bool, refuse: Any):
        self.app = app
        self.token = token
        self.loopback_only = loopback_only
        self.refuse = refuse
        #: The session keys the station handed out, oldest first (a dict keeps their order).
        self.sessions: dict[str, None] = {}

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        send = _with_security_headers(send)
        refusal = self._refusal(scope, headers, host)
        if refusal is not None:
            await self.refuse(scope, receive, send, *refusal)
            return
        if scope["type"] == "http" and scope.get("method") == "POST" and scope.get("path") == SIGN_IN_PATH:
            await self._sign_in(scope, receive, send)
            return
        query = parse_qs(scope.get("query_string", b"").decode("latin-1"))
        if self.token and "token" in query and scope["type"] == "http":
            # the address carried the token: swap it for the cookie and clean the address bar
            rest = urlencode([(k, v) for k, values in query.items() if k != "token" for v in values])
            clean = scope.get("path", "/") + (f"?{rest}" if rest else "")
            await _answer(send, 200, token_handover_page(clean), "text/html", self._cookie(scope))
            return
        await self.app(scope, _bounded(receive), send)

    def _refusal(self, scope: dict[str, Any], headers: dict[str, str], host: str) -> tuple[int, str] | None:
        name = urlsplit("//" + host).hostname or ""
        if self.loopback_only and not is_loopback(name):
            return 421, "this station answers on loopback only"
        reason = foreign_request(scope, headers, host)
        if reason is not None:
            return 403, reason
        length = headers.get("content-length", "0")
        if not length.isdigit() or len(length) > 12 or int(length) > MAX_BODY_BYTES:
            return 413, f"a request to the station carries at most {MAX_BODY_BYTES // 1024} kB"
        signing_in = scope.get("path") == SIGN_IN_PATH
        if self.token and not signing_in and not self._has_token(scope, headers):
            return 401, "sign in with the station's access token"
        return None

    def _cookie_name(self, scope: dict[str, Any]) -> str:
        server = scope.get("server") or ("", 0)
        return f"{TOKEN_COOKIE}_{server[1]}"

    def _cookie(self, scope: dict[str, Any]) -> tuple[bytes, bytes]:
        """A new session's cookie: a random key, not the token (the browser sends the cookie to
        every port of this host); not readable by scripts, never sent on another site's
        request."""
        assert self.token is not None
        key = secrets.token_urlsafe(32)
        self.sessions[key] = None
        while len(self.sessions) > MAX_SESSIONS:
            del self.sessions[next(iter(self.sessions))]
        value = f"{self._cookie_name(scope)}={key}; Path=/; HttpOnly; SameSite=Strict"
        return b"set-cookie", value.encode()

    def _has_token(self, scope: dict[str, Any], headers: dict[str, str]) -> bool:
        assert self.token is not None
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
        given = given or headers.get("x-station-token", "")
        if given:
            return hmac.compare_digest(given.encode("utf-8", "replace"), self.token.encode())
        name = self._cookie_name(scope)
        for part in headers.get("cookie", "").split(";"):
            key, _, value = part.strip().partition("=")
            if key == name:
                offered = value.encode("utf-8", "replace")
                return any(hmac.compare_digest(offered, k.encode()) for k in self.sessions)
        return False

    async def _sign_in(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        """POST /sign-in (the sign-in page's form, same-origin like every form): the cookie and
        on to the station, or the sign-in page again."""
        body = b""
        more = True
        while more:
            message = await receive()
            body += message.get("body", b"")
            more = message.get("more_body", False) and len(body) <= MAX_BODY_BYTES
        given = parse_qs(body[:MAX_BODY_BYTES].decode("latin-1")).get("token", [""])[0]
        if not self.token or not hmac.compare_digest(given.encode("latin-1"), self.token.encode()):
            await self.refuse(scope, receive, send, 401, "that is not the station's access token")
            return
        await _answer(send, 303, b"", "text/plain", self._cookie(scope), (b"location", b"/"))


def _with_security_headers(send: Any) -> Any:
    async def sending(message: dict[str, Any]) -> None:
        if message["type"] == "http.response.start":
            present = {k.lower() for k, _ in message.get("headers", [])}
            added = [(k.encode(), v.encode()) for k, v in PAGE_SECURITY_HEADERS if k.encode() not in present]
            message = {**message, "headers": [*message.get("headers", []), *added]}
        await send(message)

    return sending


def _bounded(receive: Any) -> Any:
    """``receive`` that refuses a body beyond :data:`MAX_BODY_BYTES` (one sent without a length)."""
    seen = 0

    async def receiving() -> dict[str, Any]:
        nonlocal seen
        message: dict[str, Any] = await receive()
        if message["type"] == "http.request":
            seen += len(message.get("body", b""))
            if seen > MAX_BODY_BYTES:
                return {"type": "http.disconnect"}
        return message

    return receiving


async def _answer(send: Any, status: int, body: bytes, media: str, *headers: tuple[bytes, bytes]) -> None:
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", f"{media}; charset=utf-8".encode()),
                (b"content-length", str(len(body)).encode()),
                (b"cache-control", b"no-store"),
                *headers,
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})

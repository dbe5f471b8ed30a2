"""Who may talk to the station: loopback by default; another interface only with a token.

* :func:`check_bind` refuses a non-loopback interface without a token.
* :class:`AccessMiddleware` refuses a request without the token (when one is set), a request
  whose ``Host`` is not the station's on loopback (a page of another site that rebinds its
  name to 127.0.0.1), and a form or websocket from a page of another origin.
"""

from __future__ import annotations

import hmac
import ipaddress
from typing import Any
from urllib.parse import parse_qs, urlsplit

from spacecal.core.errors import InvalidInputError

#: The cookie a browser keeps the token in once it has opened ``/?token=...``.
TOKEN_COOKIE = "spacecal_station_token"
#: The names the station answers to on loopback.
LOOPBACK_NAMES = ("127.0.0.1", "localhost", "::1", "[::1]")


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses."""
    if host.strip("[]").lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def check_bind(host: str, token: str | None) -> None:
    """Refuse to listen off loopback without a token.

    Raises
    ------
    InvalidInputError
        ``host`` is not a loopback interface and no token was given, or the token is too short.
    """
    if token is not None and len(token) < 16:
        raise InvalidInputError("--token must be at least 16 characters")
    if not is_loopback(host) and not token:
        raise InvalidInputError(
            f"the station listens on {host} only with --token TOKEN (16+ characters): anyone who can "
            "reach that interface could otherwise move the robot"
        )


class AccessMiddleware:
    """ASGI middleware that lets through only the requests the station should answer.

    Parameters
    ----------
    app : ASGI application
    token : str or None
        Required on every request (query ``token``, header ``X-Station-Token`` or the cookie)
        when given.
    loopback_only : bool
        Also refuse a ``Host`` header that does not name loopback.
    """

    def __init__(self, app: Any, token: str | None, loopback_only: bool):
        self.app = app
        self.token = token
        self.loopback_only = loopback_only

    async def __call__(self, scope: dict[str, Any], receive: Any, send: Any) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
        host = headers.get("host", "")
        refusal = self._refusal(scope, headers, host)
        if refusal is not None:
            await _refuse(scope, receive, send, *refusal)
            return
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [None])[0]
        if self.token and given and scope["type"] == "http" and scope.get("method") == "GET":
            # keep the token in a cookie the page's own requests carry from now on
            async def send_with_cookie(message: dict[str, Any]) -> None:
                if message["type"] == "http.response.start":
                    cookie = f"{TOKEN_COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
                    message = {
                        **message,
                        "headers": [*message.get("headers", []), (b"set-cookie", cookie.encode())],
                    }
                await send(message)

            await self.app(scope, receive, send_with_cookie)
            return
        await self.app(scope, receive, send)

    def _refusal(self, scope: dict[str, Any], headers: dict[str, str], host: str) -> tuple[int, str] | None:
        name = urlsplit("//" + host).hostname or ""
        if self.loopback_only and not is_loopback(name):
            return 421, "this station answers on loopback only"
        if self.token and not self._has_token(scope, headers):
            return 403, "the station needs its access token (open the address it printed, with ?token=...)"
        origin = headers.get("origin")
        unsafe = scope["type"] == "websocket" or scope.get("method") not in ("GET", "HEAD", "OPTIONS")
        if unsafe and origin and origin != "null" and urlsplit(origin).netloc != host:
            return 403, "a request from another site's page is refused"
        return None

    def _has_token(self, scope: dict[str, Any], headers: dict[str, str]) -> bool:
        assert self.token is not None
        given = parse_qs(scope.get("query_string", b"").decode("latin-1")).get("token", [""])[0]
        given = given or headers.get("x-station-token", "")
        if not given:
            for part in headers.get("cookie", "").split(";"):
                key, _, value = part.strip().partition("=")
                if key == TOKEN_COOKIE:
                    given = value
        return hmac.compare_digest(given.encode(), self.token.encode())


async def _refuse(scope: dict[str, Any], receive: Any, send: Any, status: int, text: str) -> None:
    if scope["type"] == "websocket":
        await receive()  # the connect event
        await send({"type": "websocket.close", "code": 1008, "reason": text[:120]})
        return
    body = text.encode()
    await send(
        {
            "type": "http.response.start",
            "status": status,
            "headers": [
                (b"content-type", b"text/plain; charset=utf-8"),
                (b"content-length", str(len(body)).encode()),
            ],
        }
    )
    await send({"type": "http.response.body", "body": body})

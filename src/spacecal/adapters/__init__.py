"""Hardware adapters behind the device interfaces; each optional extra is imported lazily.

Device URLs:

* ``ur://HOST`` — a Universal Robots controller over RTDE (extra ``ur``: ur-rtde).
* ``ndi://SERIAL_PORT`` or ``ndi://HOST[:PORT]`` — an NDI tracker over the Combined API,
  serial (Polaris Vicra/Spectra) or TCP (Vega, default port 8765) (extra ``ndi``: ndicapi).
* ``igtl://HOST:PORT`` — the ``MarkerToTracker`` pose (TRANSFORM, POSITION, TDATA or QTDATA)
  from PLUS Server, 3D Slicer or another OpenIGTLink sender, read by our own reader; sending a
  calibration uses pyigtl (extra ``igtl``).
"""

from __future__ import annotations

from urllib.parse import urlparse

from spacecal.core.errors import InvalidInputError, MissingExtraError


def require(module: str, extra: str):
    """Import an optional dependency, or raise naming the extra to install."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"this device needs the '{extra}' extra: pip install 'spacecal[{extra}]'"
        ) from None


def parse_device_url(url: str, schemes: tuple[str, ...]) -> tuple[str, str, int | None]:
    """Split ``scheme://host[:port]`` (or ``ndi:///dev/ttyUSB0``) into scheme, address, port."""
    parsed = urlparse(url)
    if parsed.scheme not in schemes:
        raise InvalidInputError(
            f"device {url!r}: expected one of {', '.join(s + '://' for s in schemes)} or sim"
        )
    if parsed.path and not parsed.netloc:  # a serial device path
        return parsed.scheme, parsed.path, None
    if not parsed.hostname:
        raise InvalidInputError(f"device {url!r} names no host")
    try:
        port = parsed.port
    except ValueError:
        raise InvalidInputError(f"device {url!r} has an invalid port") from None
    return parsed.scheme, parsed.hostname, port

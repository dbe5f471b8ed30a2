"""Hardware adapters behind the device interfaces; each optional extra is imported lazily.

Device URLs are one table, :data:`DEVICE_SCHEMES`: a scheme names the adapter module that
opens it (its ``open_device(address, options)``), the device's role, its default port and the
extra it needs. A new device is one module here and one line in the table.

* ``ur://HOST`` — a Universal Robots controller over RTDE (extra ``ur``: ur-rtde).
* ``franka://HOST`` — a Franka Robotics arm (FR3) over the Franka Control Interface through
  libfranka's Python bindings (extra ``franka``: pylibfranka).
* ``ndi://SERIAL_PORT`` or ``ndi://HOST[:PORT]`` — an NDI tracker over the Combined API,
  serial (Polaris Vicra/Spectra) or TCP (Vega, default port 8765) (extra ``ndi``: ndicapi).
* ``igtl://HOST:PORT`` — the ``MarkerToTracker`` pose (TRANSFORM, POSITION, TDATA or QTDATA)
  from PLUS Server, 3D Slicer or another OpenIGTLink sender, read by our own reader; sending a
  calibration uses pyigtl (extra ``igtl``).
* ``natnet://HOST[:PORT]?body=NAME`` — OptiTrack Motive's rigid body NAME over NatNet 3.x/4.x
  (command port 1510; ``tools=A,B`` further rigid bodies, ``multicast=GROUP`` for a multicast
  stream), read by our own reader (no extra).
* ``camera://INDEX?board=FILE`` or ``camera:///FOLDER?board=FILE`` — a camera (an OpenCV capture
  device, or a folder of images) seeing a ChArUco board, ``intrinsics=FILE`` or calibrated from
  the images, ``mount=fixed|flange`` (extra ``camera``: opencv-python-headless).
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field
from urllib.parse import urlparse

from spacecal.core.errors import InvalidInputError, MissingExtraError
from spacecal.planning.motion import MotionLimits

ROBOT, TRACKER = "robot", "tracker"


@dataclass(frozen=True)
class DeviceScheme:
    """One row of the URL table.

    Attributes
    ----------
    role : str
        :data:`ROBOT` or :data:`TRACKER`.
    module : str
        The adapter module under ``spacecal.adapters``; it has ``open_device(address, options)``.
    form : str
        How the URL is written, for messages and help.
    default_port : int or None
        The port a URL without one means (None: the adapter's own ports, or a serial device).
    """

    role: str
    module: str
    form: str
    default_port: int | None = None


#: An NDI Vega's Combined API port; the OpenIGTLink port (PLUS Server's and Slicer's default).
NDI_TCP_DEFAULT_PORT, IGTL_DEFAULT_PORT = 8765, 18944
#: Motive's NatNet command port.
NATNET_DEFAULT_PORT = 1510
#: rosbridge_server's WebSocket port.
ROSBRIDGE_DEFAULT_PORT = 9090

#: The schemes whose URLs carry a query their adapter reads.
QUERY_SCHEMES = ("natnet", "camera", "ros2")
#: The schemes whose device may be a path written without a host (``camera:images``): kept as
#: written, never lower-cased.
PATH_SCHEMES = ("camera",)

#: scheme -> its row: every device URL spacecal opens.
DEVICE_SCHEMES: dict[str, DeviceScheme] = {
    "ur": DeviceScheme(ROBOT, "ur", "ur://HOST"),
    "franka": DeviceScheme(ROBOT, "franka", "franka://HOST"),
    "ndi": DeviceScheme(TRACKER, "ndi", "ndi://SERIAL_PORT_OR_HOST[:PORT]", NDI_TCP_DEFAULT_PORT),
    "igtl": DeviceScheme(TRACKER, "igtl", "igtl://HOST[:PORT]", IGTL_DEFAULT_PORT),
    "natnet": DeviceScheme(TRACKER, "natnet", "natnet://HOST[:PORT]?body=RIGID_BODY", NATNET_DEFAULT_PORT),
    "camera": DeviceScheme(TRACKER, "camera", "camera://DEVICE_OR_FOLDER?board=FILE[&intrinsics=FILE]"),
    "ros2": DeviceScheme(ROBOT, "ros2", "ros2://HOST[:PORT]?joints=...", ROSBRIDGE_DEFAULT_PORT),
}


@dataclass(frozen=True)
class DeviceAddress:
    """A parsed device URL: ``host`` is a host name, or a device path when ``serial``; ``port``
    is the URL's, else the scheme's default (None: none); ``query`` the URL's query, which
    only the adapters that take one read (``natnet://HOST?body=Marker``)."""

    scheme: str
    host: str
    port: int | None
    serial: bool = False
    query: str = ""

    @property
    def url(self) -> str:
        """The URL in one canonical form (lower-case host, the default port written out, the
        query's fields in sorted order)."""
        query = f"?{'&'.join(sorted(self.query.split('&')))}" if self.query else ""
        if self.serial:
            return f"{self.scheme}{'://' if self.host.startswith('/') else ':'}{self.host}{query}"
        url = f"{self.scheme}://{self.host}" + (f":{self.port}" if self.port is not None else "")
        return url + query


@dataclass(frozen=True)
class DeviceOptions:
    """The device settings ``acquire``, ``check`` and ``doctor`` share.

    Attributes
    ----------
    rom : tuple of str
        NDI tool definitions, the marker's first.
    tracker_rate_hz : float
        The tracker's frame rate, to turn frame numbers into seconds.
    robot_model : str or None
        The nominal robot model; None takes the one the controller names.
    control : bool
        Open the robot's control interface too (False: read-only, nothing uploaded).
    limits : MotionLimits or None
        The motion limits rotation-led moves are commanded with.
    tools : tuple of (str, str)
        Further tools the tracker reports in :attr:`~spacecal.core.ports.TrackerFrame.tools`,
        as (the name they are reported by, what the tracker knows them by): for NDI the tool
        definition (ROM) file, loaded after the marker's; for OpenIGTLink the device name
        (PLUS naming, ``PointerToTracker``).
    """

    rom: tuple[str, ...] = ()
    tracker_rate_hz: float = 20.0
    robot_model: str | None = None
    control: bool = False
    limits: MotionLimits | None = field(default=None)
    tools: tuple[tuple[str, str], ...] = ()


def schemes_of(role: str) -> tuple[str, ...]:
    """The URL schemes of one role (:data:`ROBOT` or :data:`TRACKER`)."""
    return tuple(name for name, row in DEVICE_SCHEMES.items() if row.role == role)


def device_address(url: str, role: str | None = None) -> DeviceAddress:
    """Parse a device URL of ``role`` (None: of any role), the default port filled in.

    Raises
    ------
    InvalidInputError
        Not a URL of a device of that role, no host, or a bad port.
    """
    scheme, host, port = parse_device_url(url, tuple(DEVICE_SCHEMES) if role is None else schemes_of(role))
    serial = host.startswith("/") or (scheme in PATH_SCHEMES and not urlparse(url).netloc)
    if port is None and not serial:
        port = DEVICE_SCHEMES[scheme].default_port
    query = urlparse(url).query if scheme in QUERY_SCHEMES else ""
    return DeviceAddress(scheme, host if serial else host.lower(), port, serial, query)


def canonical_url(url: str) -> str:
    """A device URL in :attr:`DeviceAddress.url`'s form, to compare two (``igtl://Host`` is
    ``igtl://host:18944``); a URL that does not parse is only stripped."""
    try:
        return device_address(url.strip()).url
    except InvalidInputError:
        return url.strip()


def open_device(url: str, role: str, options: DeviceOptions):
    """Open the device a URL names, through its adapter's ``open_device``."""
    address = device_address(url, role)
    module = importlib.import_module(f"spacecal.adapters.{DEVICE_SCHEMES[address.scheme].module}")
    return module.open_device(address, options)


def require(module: str, extra: str):
    """Import an optional dependency, or raise naming the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"this device needs the '{extra}' extra: pip install 'spacecal[{extra}]'"
        ) from None


def parse_device_url(url: str, schemes: tuple[str, ...]) -> tuple[str, str, int | None]:
    """Split ``scheme://host[:port]`` (or ``ndi:///dev/ttyUSB0``) into scheme, address, port."""
    try:
        parsed = urlparse(url)
    except ValueError as exc:  # an unclosed IPv6 bracket, "igtl://[::1"
        raise InvalidInputError(f"device {url!r}: {exc}") from None
    if parsed.scheme not in schemes:
        forms = ", ".join(DEVICE_SCHEMES[s].form if s in DEVICE_SCHEMES else s + "://" for s in schemes)
        raise InvalidInputError(f"device {url!r}: expected {forms} or sim")
    if parsed.path and not parsed.netloc:  # a serial device path
        return parsed.scheme, parsed.path, None
    if not parsed.hostname:
        raise InvalidInputError(f"device {url!r} names no host")
    try:
        port = parsed.port
    except ValueError:
        raise InvalidInputError(f"device {url!r} has an invalid port") from None
    return parsed.scheme, parsed.hostname, port

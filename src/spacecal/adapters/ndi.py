"""NDI optical trackers (Polaris Vicra/Spectra over serial, Vega over TCP) through ``ndicapi``
(extra ``ndi``), the Combined API library PLUS uses.

* Serial: ``ndiProbe`` + ``ndiOpen`` on the port, ``INIT:``, then ``COMM:`` to 115200 8N1.
  TCP: ``ndiOpenNetwork(host, port)`` (Vega default 8765), ``INIT:``.
* Each passive tool: ``PHRQ`` a handle, upload its ROM (``PVWR`` in 64-byte pieces, as
  ``ndiPVWRFromFile`` does), ``PINIT``, ``PENA`` (dynamic). The first ROM is the calibration
  marker.
* Frames: ``BX:0801`` (binary): transforms and status (0x0001) plus the transforms "not
  normally reported" (0x0800), so a tool out of the characterised volume still comes with its
  pose and the out-of-volume bit instead of plainly missing. Every generation we support
  answers ``BX`` and ``TX`` (``BX2`` is Vega-only and ndicapy has no getters for it, so it is not
  used); firmware that answers ``BX`` with ``ERROR01`` (invalid command) is read with
  ``TX:0801`` (ASCII, 1e-4 / 0.01 mm resolution) from then on. ndicapy's ``ndiCommand`` decodes
  the binary reply as text and raises ``UnicodeDecodeError`` when a length byte is >= 0x80
  (three visible tools; PlusToolkit ndicapi#46); the C side has parsed the frame by then, so
  we read it with the getters regardless.
* Each frame is decoded completely: handle status (0x01 valid, 0x02 missing, 0x04 disabled),
  the 32-bit port status (0x40 out of volume, 0x80 partially out of volume, 0x100 algorithm
  limitation, 0x200 IR interference, 0x1000 processing exception, 0x4000 fell behind), the
  system status (0x0001 communication sync error, 0x0002 too much external infrared, 0x0004
  CRC error, 0x0010 hardware failure), the frame number and the RMS fit error. Only a valid
  handle with none of those bits is an ``ok`` frame; see :func:`frame_status`.
* A transport error on one reply (bad CRC, a short or garbled reply, a reply timeout) is
  retried :data:`TRANSPORT_RETRIES` times before the tracker counts as lost. ndicapi waits 5 s
  for each read of a serial reply; over TCP it sets no receive timeout at all, so a reply that
  never comes would block for ever, and a reply that comes a byte at a time renews any timeout
  per read.
* Every ndicapi call that talks to the tracker therefore runs on a worker thread and the caller
  waits for it until a deadline per call (:data:`NDI_OPEN_DEADLINE_S`, :data:`NDI_INIT_DEADLINE_S`,
  :data:`NDI_TCP_REPLY_DEADLINE_S`, :data:`NDI_SERIAL_REPLY_DEADLINE_S`,
  :data:`NDI_CLOSE_DEADLINE_S`). A call past its deadline is a
  :class:`DeviceError` naming the command and the deadline, and the tracker counts as lost: no
  further command is sent, a TCP connection is shut down at once (which ends the blocked read),
  and the device is closed when the worker returns. ndicapy does not give out its socket; it is
  found among the process's descriptors by its peer's port (Linux, macOS).
* ndicapy's getters take the port handle as a 1-byte ``bytes``. A missing marker is the
  string ``"MISSING"``. Frame numbers count camera frames; ``time_s`` is frame number / rate.
"""

from __future__ import annotations

import contextlib
import os
import re
import socket
import stat
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path

import numpy as np

from spacecal.adapters import NDI_TCP_DEFAULT_PORT, DeviceAddress, DeviceOptions, require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import (
    FINDING_OK,
    FINDING_PROBLEM,
    FINDING_WARNING,
    FRAME_DISABLED,
    FRAME_INTERFERENCE,
    FRAME_MISSING,
    FRAME_OK,
    FRAME_OUT_OF_VOLUME,
    FRAME_PARTIALLY_OUT_OF_VOLUME,
    FRAME_PROCESSING_EXCEPTION,
    DeviceFinding,
    DeviceIdentity,
    TrackerFrame,
    refused_poses_finding,
)
from spacecal.geometry.transforms import transform_from_position_quaternion

VEGA_DEFAULT_PORT = NDI_TCP_DEFAULT_PORT
#: The reply option we ask for: transforms and status, including "not normally reported" ones.
REPLY_OPTION = "0801"

#: Handle status byte of a BX reply.
HANDLE_VALID, HANDLE_MISSING, HANDLE_DISABLED = 0x01, 0x02, 0x04
#: Port status bits (BX/TX replies, 32 bits).
PORT_OCCUPIED = 0x0001
PORT_INITIALISED = 0x0010
PORT_ENABLED = 0x0020
PORT_OUT_OF_VOLUME = 0x0040
PORT_PARTIALLY_OUT_OF_VOLUME = 0x0080
PORT_ALGORITHM_LIMITATION = 0x0100
PORT_IR_INTERFERENCE = 0x0200
PORT_PROCESSING_EXCEPTION = 0x1000
PORT_FELL_BEHIND = 0x4000
#: System status bits (16 bits after the last handle).
SYSTEM_COMM_SYNC_ERROR = 0x0001
SYSTEM_TOO_MUCH_INFRARED = 0x0002
SYSTEM_COMM_CRC_ERROR = 0x0004
SYSTEM_HARDWARE_FAILURE = 0x0010

#: ndicapi error codes: the device's "invalid command" reply, and the transport errors that
#: are worth another try (bad CRC on the reply, a reply timeout, a garbled reply).
NDI_INVALID_COMMAND = 0x01
NDI_BAD_CRC, NDI_TIMEOUT, NDI_BAD_REPLY = 0x0100, 0x0103, 0x0201
TRANSPORT_ERRORS = (NDI_BAD_CRC, NDI_TIMEOUT, NDI_BAD_REPLY)
#: Extra attempts after a transport error before the tracker counts as lost.
TRANSPORT_RETRIES = 2
#: Serial probes before "no NDI tracker answers".
PROBE_ATTEMPTS = 3
#: A tool definition is written as its first kB, zero-padded, in ``PVWR`` commands of 64 bytes.
ROM_BYTES, PVWR_CHUNK_BYTES = 1024, 64

#: Deadline of opening the tracker (s): ``ndiOpenNetwork`` connects with no timeout of its own
#: (an address where nothing answers takes about 2 min of TCP retries); one ``ndiProbe`` or
#: ``ndiOpen`` of a serial port, which waits 5 s at most for the tracker's reset reply. A tracker
#: that is there answers well within a second.
NDI_OPEN_DEADLINE_S = 10.0
#: Deadline of ``INIT:`` (s): a tracker's first initialisation takes up to 5 s (PLUS waits that
#: long for it); 2 s more for a loaded computer.
NDI_INIT_DEADLINE_S = 7.0
#: Deadline of any other command and its reply over TCP (s): the tracker answers within one camera
#: frame (17 ms on a Vega; PLUS waits 100 ms), and ndicapi sets no receive timeout of its own, so
#: without this a tracker that stops answering would block ``doctor`` and a run for ever. Generous
#: for a loaded computer.
NDI_TCP_REPLY_DEADLINE_S = 3.0
#: Deadline of any other command and its reply over serial (s): ndicapi times a serial read out
#: itself after 5 s, a transport error that is retried (:data:`TRANSPORT_RETRIES`); this lets it
#: say so first, and still ends a reply that keeps coming a byte at a time.
NDI_SERIAL_REPLY_DEADLINE_S = 7.0
#: Deadline of ``TSTOP:`` when closing (s): a tracker that does not take it is closed anyway.
NDI_CLOSE_DEADLINE_S = 2.0


class _Call:
    """One blocking ndicapi call on a daemon thread of its own, so its caller can stop waiting.

    ndicapy releases the GIL while it waits for the tracker, so the caller's wait (and a Ctrl-C)
    goes on. A daemon thread, not an executor: a call that never returns must not keep the
    process from exiting.
    """

    def __init__(self, function: Callable, args: tuple):
        self.value = None
        self.error: BaseException | None = None
        self._done = threading.Event()
        self._lock = threading.Lock()
        self._then: Callable[[_Call], None] | None = None
        self.thread = threading.Thread(target=self._run, args=(function, args), name="ndi-call", daemon=True)
        self.thread.start()

    def _run(self, function: Callable, args: tuple) -> None:
        try:
            self.value = function(*args)
        except BaseException as exc:  # handed to the caller, who decides
            self.error = exc
        with self._lock:
            self._done.set()
            then = self._then
        if then is not None:
            with contextlib.suppress(Exception):
                then(self)

    def wait(self, timeout_s: float) -> bool:
        """Whether the call ended within ``timeout_s`` (s). Waited in slices of 0.1 s: a signal
        the kernel handed to another thread (Ctrl-C goes to the process) runs its handler in
        the main thread only once the main thread's wait returns."""
        deadline = time.monotonic() + timeout_s
        while True:
            left_s = deadline - time.monotonic()
            if self._done.wait(min(max(left_s, 0.0), 0.1)):
                return True
            if left_s <= 0.0:
                return False

    @property
    def done(self) -> bool:
        return self._done.is_set()

    def result(self):
        if self.error is not None:
            raise self.error
        return self.value

    def then(self, action: Callable[[_Call], None]) -> None:
        """Run ``action(self)`` when the call ends: now if it has, else on its thread."""
        with self._lock:
            if not self._done.is_set():
                self._then = action
                return
        action(self)


def _sockets() -> set[tuple[int, int]]:
    """The process's open sockets as (descriptor, inode): a number closed and reused for another
    socket is a new one (empty where the system does not list descriptors)."""
    for folder in ("/proc/self/fd", "/dev/fd"):
        try:
            descriptors = [int(name) for name in os.listdir(folder)]
        except (OSError, ValueError):
            continue
        found = set()
        for descriptor in descriptors:
            with contextlib.suppress(OSError):  # closed since (the listing's own, for one)
                status = os.fstat(descriptor)
                if stat.S_ISSOCK(status.st_mode):
                    found.add((descriptor, status.st_ino))
        return found
    return set()


def _connection_to(port: int, descriptors: Iterable[int]) -> socket.socket | None:
    """A duplicate of the one TCP connection to ``port`` among ``descriptors`` (ndicapi's, opened
    just now), to shut it down when a call passes its deadline; None if not exactly one."""
    if socket.getdefaulttimeout() is not None:
        return None  # a socket object made now would make ndicapi's socket non-blocking
    found = []
    for descriptor in sorted(descriptors):
        try:
            duplicate = os.dup(descriptor)
        except OSError:
            continue
        try:
            candidate = socket.socket(fileno=duplicate)
        except OSError:  # not a socket
            os.close(duplicate)
            continue
        try:
            peer = candidate.getpeername()
            matches = candidate.type == socket.SOCK_STREAM and isinstance(peer, tuple) and peer[1] == port
        except OSError:
            matches = False
        if matches:
            found.append(candidate)
        else:
            candidate.close()
    if len(found) == 1:
        return found[0]
    for candidate in found:
        candidate.close()
    return None


def frame_status(handle_result, port_status: int, system_status: int) -> str:
    """The frame status of one tool from everything a BX/TX reply says about it.

    Parameters
    ----------
    handle_result : tuple or str
        ndicapy's transform getter result: the 8 numbers, or ``"MISSING"`` / ``"DISABLED"``.
    port_status, system_status : int
        The 32-bit port status of the tool and the 16-bit system status of the frame.
    """
    if isinstance(handle_result, str):
        return FRAME_DISABLED if handle_result.upper().startswith("DISABLED") else FRAME_MISSING
    if port_status & PORT_OUT_OF_VOLUME:
        return FRAME_OUT_OF_VOLUME
    if port_status & PORT_PARTIALLY_OUT_OF_VOLUME:
        return FRAME_PARTIALLY_OUT_OF_VOLUME
    if port_status & (PORT_PROCESSING_EXCEPTION | PORT_ALGORITHM_LIMITATION | PORT_FELL_BEHIND) or (
        system_status & (SYSTEM_COMM_SYNC_ERROR | SYSTEM_HARDWARE_FAILURE)
    ):
        return FRAME_PROCESSING_EXCEPTION
    if port_status & PORT_IR_INTERFERENCE or system_status & SYSTEM_TOO_MUCH_INFRARED:
        return FRAME_INTERFERENCE
    return FRAME_OK


#: The lines of a ``VER 4`` reply that name the serial number and the firmware build.
_VER_SERIAL = re.compile(r"^\s*(?:NDI\s+)?(?:S/N|Serial Number)\s*:\s*(\S+)", re.IGNORECASE | re.MULTILINE)
_VER_FREEZE_TAG = re.compile(r"^\s*Freeze Tag\s*:\s*(.+?)\s*$", re.IGNORECASE | re.MULTILINE)


def identity_from_version_text(text: str) -> DeviceIdentity:
    """Model, serial and firmware from an NDI ``VER 4`` reply: its first line names the
    control firmware ("Polaris Vega Control Firmware"), an ``NDI S/N:`` line the serial number
    and the ``Freeze Tag:`` line the firmware build (the line scikit-surgerynditracker reads to
    choose BX or TX)."""
    lines = text.strip().splitlines()
    first = lines[0].strip() if lines else ""
    model = re.sub(r"\s*control firmware\s*$", "", first, flags=re.IGNORECASE) or None
    serial = _VER_SERIAL.search(text)
    freeze = _VER_FREEZE_TAG.search(text)
    return DeviceIdentity(
        model=model,
        serial=serial.group(1) if serial else None,
        firmware=freeze.group(1) if freeze else None,
    )


#: Hexadecimal digits of a reply, ASCII only: ``int(text, 16)`` also takes ``0x``, ``_``, spaces
#: and digits of other scripts, which no NDI reply holds.
_HEX_DIGITS = "0123456789ABCDEFabcdef"
#: A ``PHSR`` reply (after ndicapi took its CRC off): 2 hex digits counting the port handles,
#: then 2 hex digits of each handle and 3 of its status.
_PHSR_ENTRY_CHARS = 5


def _reply_text(reply: object, limit: int = 40) -> str:
    """A reply as a short, printable quotation for an error message."""
    text = repr(reply if isinstance(reply, str) else str(reply))
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _hex(text: str, what: str, reply: object) -> int:
    """The value of ``text``, ASCII hexadecimal digits only, else a DeviceError naming ``what``."""
    if not text or any(c not in _HEX_DIGITS for c in text):
        raise DeviceError(f"the NDI tracker sent {what} that is not hexadecimal: {_reply_text(reply)}")
    return int(text, 16)


def port_handle(reply: object) -> int:
    """The port handle of a ``PHRQ`` reply (2 hex digits, CRC taken off).

    Raises
    ------
    DeviceError
        The reply is anything else.
    """
    text = reply.strip() if isinstance(reply, str) else ""
    if len(text) != 2:
        raise DeviceError(
            f"the NDI tracker sent a PHRQ reply that is not a port handle: {_reply_text(reply)}"
        )
    return _hex(text, "a PHRQ reply", reply)


def port_handle_statuses(reply: object) -> list[tuple[int, int]]:
    """(handle, port status) of each port handle of a ``PHSR`` reply (CRC taken off).

    Raises
    ------
    DeviceError
        The reply is not 2 hex digits of a count followed by that many 5-hex-digit entries.
    """
    text = reply.strip() if isinstance(reply, str) else ""
    count = _hex(text[:2], "a PHSR reply", reply)
    body = text[2:]
    if len(body) != count * _PHSR_ENTRY_CHARS:
        raise DeviceError(
            f"the NDI tracker sent a PHSR reply of {len(body)} characters for {count} port "
            f"handle(s) (expected {count * _PHSR_ENTRY_CHARS}): {_reply_text(reply)}"
        )
    entries = [body[k : k + _PHSR_ENTRY_CHARS] for k in range(0, len(body), _PHSR_ENTRY_CHARS)]
    return [
        (_hex(entry[:2], "a PHSR reply", reply), _hex(entry[2:], "a PHSR reply", reply)) for entry in entries
    ]


class NDITracker:
    """An NDI tracker following one passive marker (Tracker protocol).

    Parameters
    ----------
    address : str
        Serial device path (``/dev/ttyUSB0``) or host name / IP address.
    port : int, optional
        TCP port; None means serial.
    rom_files : list of str
        Tool definition files; the first is the calibration marker, each further one a tool
        reported in :attr:`TrackerFrame.tools` under its name.
    rate_hz : float
        Camera frame rate, to turn frame numbers into seconds (Vicra 20, Spectra/Vega 60).
    reply : str
        ``"bx"`` (binary, default) or ``"tx"`` (ASCII).
    tool_names : sequence of str, optional
        The names of the further tools, one per ROM after the first (default: each ROM file's
        name without its suffix, ``pointer.rom`` is ``pointer``).
    """

    def __init__(
        self,
        address: str,
        port: int | None,
        rom_files,
        rate_hz: float = 20.0,
        reply: str = "bx",
        tool_names: Sequence[str] | None = None,
    ):
        self._ndi = require("ndicapy", "ndi")
        if not rom_files:
            raise InvalidInputError("an NDI tracker needs the marker's ROM file (--rom)")
        for rom in rom_files:
            if not Path(rom).is_file():
                raise InvalidInputError(f"ROM file {rom} not found")
        #: The further tools' names, in the order of their ROMs (after the marker's).
        self.tool_names = further_tool_names(list(rom_files)[1:], tool_names)
        self.rate_hz = rate_hz
        self.reply = reply
        self.serial = port is None
        #: Why the tracker counts as lost (a call passed its deadline), or None.
        self._lost: str | None = None
        #: A call an interruption stopped waiting for: (call, deadline on the monotonic clock,
        #: what it did, its deadline in s, its ``late`` action), or None.
        self._pending: tuple | None = None
        self._device = None
        self._connection: socket.socket | None = None
        self._released = False
        self._release_lock = threading.Lock()
        self._reply_deadline_s = NDI_SERIAL_REPLY_DEADLINE_S if self.serial else NDI_TCP_REPLY_DEADLINE_S
        try:
            self._open(address, port)
            self._set_up(rom_files)
        except BaseException:
            self.close()
            raise
        self._marker = bytes([self.handles[0]])
        self._tool_handles = {name: bytes([h]) for name, h in zip(self.tool_names, self.handles[1:])}
        self._last_frame_number = -1
        self._bx_answered = False
        self._last_frame_at = time.monotonic()
        #: How many BX replies hit ndicapi#46 and were read through the getters.
        self.decode_faults_handled = 0
        #: How many replies failed in transport (CRC, garbled, timeout) and were asked again.
        self.transport_errors_retried = 0

    def _open(self, address: str, port: int | None) -> None:
        ndi = self._ndi
        where = address + (f":{port}" if port else "")
        close = ndi.ndiClose if self.serial else ndi.ndiCloseNetwork

        def close_late(call: _Call) -> None:  # an open that ends after its deadline
            if call.value:
                close(call.value)

        if self.serial:
            # ndiProbe gives the first reply only 0.1 s; a tracker busy just after power-up or
            # a loaded host can miss that, so it is asked again before we give up
            for _ in range(PROBE_ATTEMPTS):
                if self._call(f"probing {where}", NDI_OPEN_DEADLINE_S, ndi.ndiProbe, address) == ndi.NDI_OKAY:
                    break
            else:
                raise DeviceError(f"no NDI tracker answers on {address}")
            self._device = self._call(
                f"opening {where}", NDI_OPEN_DEADLINE_S, ndi.ndiOpen, address, late=close_late
            )
        else:
            before = _sockets()
            self._device = self._call(
                f"connecting to {where}",
                NDI_OPEN_DEADLINE_S,
                ndi.ndiOpenNetwork,
                address,
                port,
                late=close_late,
            )
            if self._device:
                opened = {descriptor for descriptor, _ in _sockets() - before}
                self._connection = _connection_to(int(port or 0), opened)
        if not self._device:
            raise DeviceError(f"could not open the NDI tracker at {where}")

    def _set_up(self, rom_files) -> None:
        ndi = self._ndi
        self._command("INIT:")
        if self.serial:
            self._command(f"COMM:{ndi.NDI_115200:d}{ndi.NDI_8N1:03d}{ndi.NDI_NOHANDSHAKE:d}")
        self.handles = []
        for rom in rom_files:
            handle = port_handle(self._command("PHRQ:*********1****"))
            self._upload(handle, Path(rom))
            self._command(f"PINIT:{handle:02X}")
            self._command(f"PENA:{handle:02X}D")
            self.handles.append(handle)
        self._command("TSTART:")

    def _upload(self, handle: int, rom: Path) -> None:
        """Write a tool definition to a port handle: what ``ndiPVWRFromFile`` does (the first
        1 kB of the file, zero-padded, in 64-byte ``PVWR`` commands), one command at a time so
        each has its deadline; ndicapy holds the GIL through ``ndiPVWRFromFile``, where no
        deadline could end it."""
        data = rom.read_bytes()[:ROM_BYTES].ljust(ROM_BYTES, b"\0")
        for address in range(0, ROM_BYTES, PVWR_CHUNK_BYTES):
            chunk = data[address : address + PVWR_CHUNK_BYTES]
            self._command(
                f"PVWR:{handle:02X}{address:04X}{chunk.hex().upper()}", what=f"uploading {rom.name}"
            )

    def _call(self, what: str, deadline_s: float, function: Callable, *args, late=None):
        """``function(*args)`` (an ndicapi call that talks to the tracker), waited for at most
        ``deadline_s`` (s).

        Raises
        ------
        DeviceError
            The tracker is lost already, or the call did not end by its deadline (it is lost
            from then on: its TCP connection is shut down and the device closed once the call
            returns; ``late(call)`` runs then instead, for a call that opens the device).
        """
        self._settle()
        call = _Call(function, args)
        deadline = time.monotonic() + deadline_s
        try:
            ended = call.wait(deadline_s)
        except BaseException:
            # Interrupted while waiting (Ctrl-C, a signal): the caller goes on at once (it
            # stops the robot), and the call is left to end by its deadline; the next call,
            # closing's TSTOP among them, waits for it first (:meth:`_settle`).
            self._pending = (call, deadline, what, deadline_s, late)
            raise
        if not ended:
            self._abandon(call, self._no_answer(what, deadline_s), late)
            raise DeviceError(self._lost)
        return call.result()

    @staticmethod
    def _no_answer(what: str, deadline_s: float) -> str:
        return f"NDI tracker lost: no answer while {what} within {deadline_s:g} s; connection closed"

    def _settle(self) -> None:
        """Before a call: the tracker is not lost, and a call an interruption left running has
        ended by its deadline (else the tracker is lost now).

        Raises
        ------
        DeviceError
            The tracker is lost.
        """
        if self._lost is not None:
            raise DeviceError(self._lost)
        if self._pending is None:
            return
        call, deadline, what, deadline_s, late = self._pending
        self._pending = None
        if not call.wait(max(0.0, deadline - time.monotonic())):
            self._abandon(call, self._no_answer(what, deadline_s), late)
            raise DeviceError(self._lost)

    def _abandon(self, call: _Call, reason: str, late=None) -> None:
        """Give up a call still running: nothing more is sent, a TCP connection is shut down
        (its blocked read ends) and the device is closed when the call returns."""
        self._lost = reason
        if self._connection is not None:
            with contextlib.suppress(OSError):
                self._connection.shutdown(socket.SHUT_RDWR)
        call.then(late if late is not None else (lambda _: self._release()))

    def _release(self) -> None:
        """Close the device, once (only when no call on it runs any more)."""
        with self._release_lock:
            if self._released:
                return
            self._released = True
        if self._device:
            with contextlib.suppress(OSError):
                (self._ndi.ndiClose if self.serial else self._ndi.ndiCloseNetwork)(self._device)
        if self._connection is not None:
            with contextlib.suppress(OSError):
                self._connection.close()

    def _check(self, what: str) -> None:
        error = self._ndi.ndiGetError(self._device)
        if error != self._ndi.NDI_OKAY:
            raise DeviceError(f"NDI tracker error while {what}: {self._ndi.ndiErrorString(error)}")

    def _command(self, text: str, what: str | None = None) -> str:
        name = text.split(":")[0]
        what = what or f"sending {name}"
        deadline_s = NDI_INIT_DEADLINE_S if name == "INIT" else self._reply_deadline_s
        reply = self._call(what, deadline_s, self._ndi.ndiCommand, self._device, text)
        self._check(what)
        return reply

    def _request(self, text: str, retries: int = TRANSPORT_RETRIES) -> tuple[str | None, int]:
        """Send a command, retrying transport errors; (reply or None, ndicapi error code).

        ndicapy raises ``OSError`` when ndicapi reports an error; the code is read back here. A
        binary reply that ndicapy cannot decode as text (ndicapi#46) was still parsed on the C
        side: the reply is None then and the getters hold the frame. A reply that does not come
        within the reply deadline is no transport error: the tracker is lost (:meth:`_call`).
        """
        ndi = self._ndi
        error = ndi.NDI_OKAY
        what = f"sending {text.split(':')[0].strip()}"
        for attempt in range(retries + 1):
            reply = None
            try:
                reply = self._call(what, self._reply_deadline_s, ndi.ndiCommand, self._device, text)
            except UnicodeDecodeError:
                self.decode_faults_handled += 1
            except DeviceError:
                raise
            except OSError:
                pass
            error = ndi.ndiGetError(self._device)
            if error not in TRANSPORT_ERRORS:
                return reply, error
            if attempt < retries:
                self.transport_errors_retried += 1
        raise DeviceError(
            f"NDI tracker lost: {retries + 1} replies in a row failed ({ndi.ndiErrorString(error)})"
        )

    def _poll(self, handle: bytes | None = None):
        """Request one frame; (frame number, transform or 'MISSING'/'DISABLED', port status,
        system status) of ``handle`` (default the marker), and fifth the further tools' {name:
        (transform or 'MISSING'/'DISABLED', port status)} of the same reply."""
        handle = self._marker if handle is None else handle
        getters = self._request_frame()
        frame_getter, transform_getter, port_getter, system_getter = getters
        tools = {
            name: (transform_getter(self._device, tool), port_getter(self._device, tool))
            for name, tool in self._tool_handles.items()
        }
        return (
            frame_getter(self._device, handle),
            transform_getter(self._device, handle),
            port_getter(self._device, handle),
            system_getter(self._device),
            tools,
        )

    def _request_frame(self):
        """Ask for one frame (BX, else TX); the ndicapy getters of its reply: frame number,
        transform, port status (each of a handle) and system status."""
        ndi = self._ndi
        if self.reply == "bx" and not self._bx_answered:
            # Firmware without BX answers "ERROR01" in ASCII, which ndicapi checks as a binary
            # reply: a bad CRC every time. Before BX has worked once, any failure means TX.
            try:
                _, error = self._request(f"BX:{REPLY_OPTION}")
            except DeviceError:
                if self._lost is not None:
                    raise
                error = NDI_INVALID_COMMAND
            if error == ndi.NDI_OKAY:
                self._bx_answered = True
            else:
                self.reply = "tx"
        elif self.reply == "bx":
            _, error = self._request(f"BX:{REPLY_OPTION}")
            if error != ndi.NDI_OKAY:
                raise DeviceError(f"NDI tracker error while sending BX: {ndi.ndiErrorString(error)}")
        if self.reply == "bx":
            return ndi.ndiGetBXFrame, ndi.ndiGetBXTransform, ndi.ndiGetBXPortStatus, ndi.ndiGetBXSystemStatus
        _, error = self._request(f"TX:{REPLY_OPTION}")
        if error != ndi.NDI_OKAY:
            raise DeviceError(f"NDI tracker error while sending TX: {ndi.ndiErrorString(error)}")
        return ndi.ndiGetTXFrame, ndi.ndiGetTXTransform, ndi.ndiGetTXPortStatus, ndi.ndiGetTXSystemStatus

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                frame_number, transform, port_status, system_status, tools = self._poll()
            except DeviceError:
                raise
            except OSError as exc:
                raise DeviceError(f"NDI tracker lost: {exc}") from None
            if isinstance(transform, str) and transform.upper().startswith("DISABLED"):
                # a disabled handle carries no frame number: count camera periods on our clock
                periods = int((time.monotonic() - self._last_frame_at) * self.rate_hz)
                frame_number = self._last_frame_number + periods if periods > 0 else -1
            if frame_number > self._last_frame_number:
                break
            if time.monotonic() > deadline:
                raise DeviceError(f"no new NDI frame for {timeout_s:.1f} s: tracker unplugged or stalled")
            time.sleep(0.25 / self.rate_hz)
        self._last_frame_number = frame_number
        self._last_frame_at = time.monotonic()
        return self._frame(frame_number, transform, port_status, system_status, tools)

    def _frame(
        self, frame_number: int, transform, port_status: int, system_status: int, tools: dict | None = None
    ) -> TrackerFrame:
        #: The raw status words of the newest frame, for diagnostics.
        self.last_port_status, self.last_system_status = int(port_status), int(system_status)
        status = frame_status(transform, port_status, system_status)
        time_s = frame_number / self.rate_hz
        poses: dict[str, np.ndarray | None] = {}
        statuses: dict[str, str] = {}
        for name, (tool_transform, tool_port) in (tools or {}).items():
            tool_status = frame_status(tool_transform, tool_port, system_status)
            tool_pose = _pose_of(tool_transform)
            poses[name] = tool_pose
            statuses[name] = (
                tool_status if tool_pose is not None or isinstance(tool_transform, str) else FRAME_MISSING
            )
        pose = _pose_of(transform)
        if pose is None:  # "MISSING" or "DISABLED", or no usable rotation: no pose
            return TrackerFrame(
                time_s,
                int(frame_number),
                status if isinstance(transform, str) else FRAME_MISSING,
                None,
                tools=poses,
                tool_statuses=statuses,
            )
        # the pose is kept whatever the status: a doubtful frame is recorded as such
        return TrackerFrame(
            time_s, int(frame_number), status, pose, float(transform[7]), tools=poses, tool_statuses=statuses
        )

    def identity(self) -> DeviceIdentity:
        """The tracker's model, serial number and firmware, from its ``VER 4`` text; None for
        what the text does not say or a tracker that does not answer."""
        try:
            version, error = self._request("VER:4")
        except DeviceError:
            return DeviceIdentity()
        if not version or error != self._ndi.NDI_OKAY:
            return DeviceIdentity()
        return identity_from_version_text(version)

    def preflight(self, duration_s: float = 1.0) -> list[DeviceFinding]:
        """Read-only checks: tracker and firmware, reply form, tools and their status, the
        camera frame rate measured over ``duration_s``."""
        findings = []
        ndi = self._ndi
        version, error = self._request("VER:4")
        api, api_error = self._request("APIREV ")
        identity = (
            identity_from_version_text(version) if version and error == ndi.NDI_OKAY else DeviceIdentity()
        )
        name = identity.model or "NDI tracker"
        serial = f", serial number {identity.serial}" if identity.serial else ""
        revision = api.strip() if api and api_error == ndi.NDI_OKAY else "unknown (APIREV not answered)"
        findings.append(
            DeviceFinding(
                FINDING_OK,
                "tracker",
                f"{name}{serial}, API revision {revision}, over {'serial' if self.serial else 'TCP'}",
            )
        )
        start = time.monotonic()
        first = last = None
        frames = []
        while time.monotonic() - start < duration_s:
            frame_number, transform, port_status, system_status, tools = self._poll()
            if first is None:
                first = (frame_number, time.monotonic())
            if last is None or frame_number != last[0]:
                last = (frame_number, time.monotonic())
                frames.append(self._frame(frame_number, transform, port_status, system_status, tools))
            time.sleep(0.2 / self.rate_hz)
        findings.append(
            DeviceFinding(
                FINDING_OK if self.reply == "bx" else FINDING_WARNING,
                "reply form",
                "binary BX replies"
                if self.reply == "bx"
                else "this firmware does not answer BX: ASCII TX replies (0.01 mm, 1e-4 resolution)",
            )
        )
        if first is not None and last is not None and last[1] > first[1]:
            rate = (last[0] - first[0]) / (last[1] - first[1])
            close = abs(rate - self.rate_hz) <= 0.2 * self.rate_hz
            findings.append(
                DeviceFinding(
                    FINDING_OK if close else FINDING_WARNING,
                    "frame rate",
                    f"{rate:.1f} Hz measured over {duration_s:.0f} s"
                    + (
                        "" if close else f"; the configured {self.rate_hz:g} Hz sets the sample times: fix it"
                    ),
                )
            )
        else:
            findings.append(DeviceFinding(FINDING_PROBLEM, "frame rate", "the frame number did not advance"))
        reply, error = self._request("PHSR:00")
        if error == ndi.NDI_OKAY and reply:
            try:
                ports = port_handle_statuses(reply)
            except DeviceError as exc:
                # a tracker whose replies cannot be read does not pass, whatever else it says
                findings.append(DeviceFinding(FINDING_PROBLEM, "tools", str(exc)))
            else:
                text = ", ".join(
                    f"{handle:02X} {'enabled' if status & PORT_ENABLED else 'not enabled'}"
                    for handle, status in ports
                )
                findings.append(DeviceFinding(FINDING_OK, "tools", f"{len(ports)} port handle(s): {text}"))
        statuses = [f.status for f in frames]
        seen = statuses.count(FRAME_OK)
        # an occasional dropout is normal; mostly not ok is not
        level = FINDING_OK if statuses and seen >= 0.8 * len(statuses) else FINDING_WARNING
        summary = ", ".join(f"{statuses.count(s)} {s}" for s in dict.fromkeys(statuses)) or "no frame"
        findings.append(
            DeviceFinding(
                level,
                "marker status",
                f"marker handle {self.handles[0]:02X}: {summary}"
                + ("" if level == FINDING_OK else " (move the marker into the middle of the volume)"),
            )
        )
        refused = refused_poses_finding(sum(f.refused_pose for f in frames), len(frames))
        if refused is not None:
            findings.append(refused)
        return findings

    def close(self) -> None:
        """Stop tracking and close; a device that is already gone is not an error here.

        A call an interruption left running is waited for first, up to its own deadline (an
        answering tracker ends it within a frame), so that ``TSTOP`` reaches the tracker; then
        ``TSTOP`` within :data:`NDI_CLOSE_DEADLINE_S`. A lost tracker's device is closed when
        its last call returns."""
        if self._lost is not None or not self._device:
            if not self._device:
                self._release()
            return
        with contextlib.suppress(OSError, DeviceError):  # DeviceError: lost by now; closed on return
            self._call("sending TSTOP", NDI_CLOSE_DEADLINE_S, self._ndi.ndiCommand, self._device, "TSTOP:")
        if self._lost is None:
            self._release()


def _pose_of(transform) -> np.ndarray | None:
    """The pose (4, 4), mm, of an ndicapy transform (q0 qx qy qz tx ty tz rms); None for
    ``MISSING``/``DISABLED`` or a quaternion that is no rotation."""
    if isinstance(transform, str):
        return None
    q0, qx, qy, qz, tx, ty, tz, _ = transform
    norm = float(np.linalg.norm([q0, qx, qy, qz]))
    if not np.isfinite(norm) or norm < 0.5:  # no usable rotation: never a pose
        return None
    return transform_from_position_quaternion([tx, ty, tz], np.array([q0, qx, qy, qz]) / norm)


def further_tool_names(rom_files: Sequence, names: Sequence[str] | None = None) -> tuple[str, ...]:
    """The names of the tools after the marker: ``names`` (one per ROM) or each ROM file's stem
    (``pointer.rom`` twice: ``pointer``, ``pointer-2``).

    Raises
    ------
    InvalidInputError
        Not one name per ROM, an empty name, or one name twice.
    """
    if names is None:
        # the same definition loaded twice (a second tool of one kind) gets a numbered name
        stems = [Path(rom).stem for rom in rom_files]
        names = [
            stem if stems[:k].count(stem) == 0 else f"{stem}-{stems[:k].count(stem) + 1}"
            for k, stem in enumerate(stems)
        ]
    chosen = tuple(names)
    if len(chosen) != len(rom_files):
        raise InvalidInputError(
            f"{len(chosen)} tool name(s) for {len(rom_files)} tool definition(s) after the marker's"
        )
    for name in chosen:
        if not isinstance(name, str) or not name.strip():
            raise InvalidInputError(f"a tracked tool needs a name, got {name!r}")
    repeated = sorted({name for name in chosen if chosen.count(name) > 1})
    if repeated:
        raise InvalidInputError(f"two tools are named {repeated[0]!r}: give each tool its own name")
    return chosen


def open_device(address: DeviceAddress, options: DeviceOptions) -> NDITracker:
    """The ``ndi://`` row of the URL table (:data:`spacecal.adapters.DEVICE_SCHEMES`): a serial
    port (``ndi:///dev/ttyUSB0``) or a TCP host (a Vega). ROMs after the marker's are tools
    named by their files' stems; ``options.tools`` adds (name, ROM file) pairs after those."""
    if not options.rom:
        raise InvalidInputError("an NDI tracker needs the marker's tool definition: --rom FILE")
    further = list(options.rom[1:]) + [rom for _, rom in options.tools]
    names = [Path(rom).stem for rom in options.rom[1:]] + [name for name, _ in options.tools]
    return NDITracker(
        address.host,
        None if address.serial else address.port,
        [options.rom[0], *further],
        rate_hz=options.tracker_rate_hz,
        tool_names=names,
    )

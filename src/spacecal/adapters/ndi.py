"""NDI optical trackers (Polaris Vicra/Spectra over serial, Vega over TCP) through ``ndicapi``
(extra ``ndi``), the Combined API library PLUS uses.

* Serial: ``ndiProbe`` + ``ndiOpen`` on the port, ``INIT:``, then ``COMM:`` to 115200 8N1.
  TCP: ``ndiOpenNetwork(host, port)`` (Vega default 8765), ``INIT:``.
* Each passive tool: ``PHRQ`` a handle, upload its ROM (``ndiPVWRFromFile``), ``PINIT``,
  ``PENA`` (dynamic). The first ROM is the calibration marker.
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
  for a serial reply; over TCP it sets no receive timeout, so a reply that never comes blocks.
* ndicapy's getters take the port handle as a 1-byte ``bytes``. A missing marker is the
  string ``"MISSING"``. Frame numbers count camera frames; ``time_s`` is frame number / rate.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from spacecal.adapters import require
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
    TrackerFrame,
)
from spacecal.geometry.transforms import transform_from_position_quaternion

VEGA_DEFAULT_PORT = 8765
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


class NDITracker:
    """An NDI tracker following one passive marker (Tracker protocol).

    Parameters
    ----------
    address : str
        Serial device path (``/dev/ttyUSB0``) or host name / IP address.
    port : int, optional
        TCP port; None means serial.
    rom_files : list of str
        Tool definition files; the first is the calibration marker.
    rate_hz : float
        Camera frame rate, to turn frame numbers into seconds (Vicra 20, Spectra/Vega 60).
    reply : str
        ``"bx"`` (binary, default) or ``"tx"`` (ASCII).
    """

    def __init__(self, address: str, port: int | None, rom_files, rate_hz: float = 20.0, reply: str = "bx"):
        self._ndi = require("ndicapy", "ndi")
        if not rom_files:
            raise InvalidInputError("an NDI tracker needs the marker's ROM file (--rom)")
        for rom in rom_files:
            if not Path(rom).is_file():
                raise InvalidInputError(f"ROM file {rom} not found")
        self.rate_hz = rate_hz
        self.reply = reply
        self.serial = port is None
        ndi = self._ndi
        if self.serial:
            # ndiProbe gives the first reply only 0.1 s; a tracker busy just after power-up or
            # a loaded host can miss that, so it is asked again before we give up
            for _ in range(PROBE_ATTEMPTS):
                if ndi.ndiProbe(address) == ndi.NDI_OKAY:
                    break
            else:
                raise DeviceError(f"no NDI tracker answers on {address}")
            self._device = ndi.ndiOpen(address)
        else:
            self._device = ndi.ndiOpenNetwork(address, port)
        if not self._device:
            raise DeviceError(f"could not open the NDI tracker at {address}" + (f":{port}" if port else ""))
        self._command("INIT:")
        if self.serial:
            self._command(f"COMM:{ndi.NDI_115200:d}{ndi.NDI_8N1:03d}{ndi.NDI_NOHANDSHAKE:d}")
        self.handles = []
        for rom in rom_files:
            self._command("PHRQ:*********1****")
            handle = ndi.ndiGetPHRQHandle(self._device)
            ndi.ndiPVWRFromFile(self._device, handle, str(rom))
            self._check(f"uploading {rom}")
            self._command(f"PINIT:{handle:02X}")
            self._command(f"PENA:{handle:02X}D")
            self.handles.append(handle)
        self._command("TSTART:")
        self._marker = bytes([self.handles[0]])
        self._last_frame_number = -1
        self._bx_answered = False
        self._last_frame_at = time.monotonic()
        #: How many BX replies hit ndicapi#46 and were read through the getters.
        self.decode_faults_handled = 0
        #: How many replies failed in transport (CRC, garbled, timeout) and were asked again.
        self.transport_errors_retried = 0

    def _check(self, what: str) -> None:
        error = self._ndi.ndiGetError(self._device)
        if error != self._ndi.NDI_OKAY:
            raise DeviceError(f"NDI tracker error while {what}: {self._ndi.ndiErrorString(error)}")

    def _command(self, text: str) -> str:
        reply = self._ndi.ndiCommand(self._device, text)
        self._check(f"sending {text.split(':')[0]}")
        return reply

    def _request(self, text: str, retries: int = TRANSPORT_RETRIES) -> tuple[str | None, int]:
        """Send a command, retrying transport errors; (reply or None, ndicapi error code).

        ndicapy raises ``OSError`` when ndicapi reports an error; the code is read back here. A
        binary reply that ndicapy cannot decode as text (ndicapi#46) was still parsed on the C
        side: the reply is None then and the getters hold the frame.
        """
        ndi = self._ndi
        error = ndi.NDI_OKAY
        for attempt in range(retries + 1):
            reply = None
            try:
                reply = ndi.ndiCommand(self._device, text)
            except UnicodeDecodeError:
                self.decode_faults_handled += 1
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
        system status) of ``handle`` (default the marker)."""
        ndi = self._ndi
        handle = self._marker if handle is None else handle
        if self.reply == "bx" and not self._bx_answered:
            # Firmware without BX answers "ERROR01" in ASCII, which ndicapi checks as a binary
            # reply: a bad CRC every time. Before BX has worked once, any failure means TX.
            try:
                _, error = self._request(f"BX:{REPLY_OPTION}")
            except DeviceError:
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
            return (
                ndi.ndiGetBXFrame(self._device, handle),
                ndi.ndiGetBXTransform(self._device, handle),
                ndi.ndiGetBXPortStatus(self._device, handle),
                ndi.ndiGetBXSystemStatus(self._device),
            )
        _, error = self._request(f"TX:{REPLY_OPTION}")
        if error != ndi.NDI_OKAY:
            raise DeviceError(f"NDI tracker error while sending TX: {ndi.ndiErrorString(error)}")
        return (
            ndi.ndiGetTXFrame(self._device, handle),
            ndi.ndiGetTXTransform(self._device, handle),
            ndi.ndiGetTXPortStatus(self._device, handle),
            ndi.ndiGetTXSystemStatus(self._device),
        )

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                frame_number, transform, port_status, system_status = self._poll()
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
        return self._frame(frame_number, transform, port_status, system_status)

    def _frame(self, frame_number: int, transform, port_status: int, system_status: int) -> TrackerFrame:
        #: The raw status words of the newest frame, for diagnostics.
        self.last_port_status, self.last_system_status = int(port_status), int(system_status)
        status = frame_status(transform, port_status, system_status)
        time_s = frame_number / self.rate_hz
        if isinstance(transform, str):  # "MISSING" or "DISABLED": no pose
            return TrackerFrame(time_s, int(frame_number), status, None)
        q0, qx, qy, qz, tx, ty, tz, rms = transform
        norm = float(np.linalg.norm([q0, qx, qy, qz]))
        if not np.isfinite(norm) or norm < 0.5:  # no usable rotation: never a pose
            return TrackerFrame(time_s, int(frame_number), FRAME_MISSING, None)
        pose = transform_from_position_quaternion([tx, ty, tz], np.array([q0, qx, qy, qz]) / norm)
        # the pose is kept whatever the status: a doubtful frame is recorded as such
        return TrackerFrame(time_s, int(frame_number), status, pose, float(rms))

    def preflight(self, duration_s: float = 1.0) -> list[DeviceFinding]:
        """Read-only checks: tracker and firmware, reply form, tools and their status, the
        camera frame rate measured over ``duration_s``."""
        findings = []
        ndi = self._ndi
        version, error = self._request("VER:4")
        api, api_error = self._request("APIREV ")
        name = (version or "").strip().splitlines()[0] if version and error == ndi.NDI_OKAY else "NDI tracker"
        revision = api.strip() if api and api_error == ndi.NDI_OKAY else "unknown (APIREV not answered)"
        findings.append(
            DeviceFinding(
                FINDING_OK,
                "tracker",
                f"{name}, API revision {revision}, over {'serial' if self.serial else 'TCP'}",
            )
        )
        start = time.monotonic()
        first = last = None
        frames = []
        while time.monotonic() - start < duration_s:
            frame_number, transform, port_status, system_status = self._poll()
            if first is None:
                first = (frame_number, time.monotonic())
            if last is None or frame_number != last[0]:
                last = (frame_number, time.monotonic())
                frames.append(self._frame(frame_number, transform, port_status, system_status))
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
            count = int(reply[:2], 16)
            ports = [reply[2 + 5 * k : 7 + 5 * k] for k in range(count)]
            text = ", ".join(
                f"{p[:2]} {'enabled' if int(p[2:], 16) & PORT_ENABLED else 'not enabled'}" for p in ports
            )
            findings.append(DeviceFinding(FINDING_OK, "tools", f"{count} port handle(s): {text}"))
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
        return findings

    def close(self) -> None:
        """Stop tracking and close; a device that is already gone is not an error here."""
        try:
            self._ndi.ndiCommand(self._device, "TSTOP:")
        except OSError:
            pass
        try:
            (self._ndi.ndiClose if self.serial else self._ndi.ndiCloseNetwork)(self._device)
        except OSError:
            pass

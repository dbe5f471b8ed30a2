"""NDI optical trackers (Polaris Vicra/Spectra over serial, Vega over TCP) through ``ndicapi``
(extra ``ndi``), the Combined API library PLUS uses.

* Serial: ``ndiProbe`` + ``ndiOpen`` on the port, ``INIT:``, then ``COMM:`` to 115200 8N1.
  TCP: ``ndiOpenNetwork(host, port)`` (Vega default 8765), ``INIT:``.
* Each passive tool: ``PHRQ`` a handle, upload its ROM (``ndiPVWRFromFile``), ``PINIT``,
  ``PENA`` (dynamic). The first ROM is the calibration marker.
* Frames: ``BX:0801`` (binary). ndicapy's ``ndiCommand`` decodes the binary reply as text and
  raises ``UnicodeDecodeError`` when a length byte is >= 0x80 (three visible tools; PlusToolkit
  ndicapi#46); the C side has parsed the frame by then, so we read it with the getters
  regardless. If BX fails outright we fall back to ``TX:0801`` (ASCII, 1e-4 / 0.01 mm
  resolution).
* ndicapy's getters take the port handle as a 1-byte ``bytes``. A missing marker is the
  string ``"MISSING"``. Frame numbers count camera frames; ``time_s`` is frame number / rate.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from spacecal.adapters import require
from spacecal.core.errors import DeviceError, InvalidInputError
from spacecal.core.ports import FRAME_MISSING, FRAME_OK, TrackerFrame
from spacecal.geometry.transforms import transform_from_position_quaternion

VEGA_DEFAULT_PORT = 8765


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
            if ndi.ndiProbe(address) != ndi.NDI_OKAY:
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
        #: How many BX replies hit ndicapi#46 and were read through the getters.
        self.decode_faults_handled = 0

    def _check(self, what: str) -> None:
        error = self._ndi.ndiGetError(self._device)
        if error != self._ndi.NDI_OKAY:
            raise DeviceError(f"NDI tracker error while {what}: {self._ndi.ndiErrorString(error)}")

    def _command(self, text: str) -> str:
        reply = self._ndi.ndiCommand(self._device, text)
        self._check(f"sending {text.split(':')[0]}")
        return reply

    def _poll(self):
        """Request one frame; return (frame number, transform tuple or 'MISSING')."""
        ndi = self._ndi
        if self.reply == "bx":
            try:
                ndi.ndiCommand(self._device, "BX:0801")
            except UnicodeDecodeError:
                # ndicapi#46: the reply was parsed on the C side; read it with the getters
                self.decode_faults_handled += 1
            if ndi.ndiGetError(self._device) == ndi.NDI_OKAY:
                return ndi.ndiGetBXFrame(self._device, self._marker), ndi.ndiGetBXTransform(
                    self._device, self._marker
                )
            self.reply = "tx"  # fall back to the ASCII reply
        self._command("TX:0801")
        return ndi.ndiGetTXFrame(self._device, self._marker), ndi.ndiGetTXTransform(
            self._device, self._marker
        )

    def next_frame(self, timeout_s: float) -> TrackerFrame:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                frame_number, transform = self._poll()
            except DeviceError:
                raise
            except OSError as exc:
                raise DeviceError(f"NDI tracker lost: {exc}") from None
            if frame_number > self._last_frame_number:
                break
            if time.monotonic() > deadline:
                raise DeviceError(f"no new NDI frame for {timeout_s:.1f} s: tracker unplugged or stalled")
            time.sleep(0.25 / self.rate_hz)
        self._last_frame_number = frame_number
        if isinstance(transform, str):  # "MISSING" or "DISABLED"
            return TrackerFrame(frame_number / self.rate_hz, int(frame_number), FRAME_MISSING, None)
        q0, qx, qy, qz, tx, ty, tz, rms = transform
        pose = transform_from_position_quaternion(
            [tx, ty, tz], np.array([q0, qx, qy, qz]) / np.linalg.norm([q0, qx, qy, qz])
        )
        return TrackerFrame(frame_number / self.rate_hz, int(frame_number), FRAME_OK, pose, float(rms))

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

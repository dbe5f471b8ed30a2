"""Test tools shipped with the library, as :mod:`numpy.testing` is: protocol fakes of the devices
and the command line's fuzz harness.

* :mod:`spacecal.testing.fakes`: an NDI tracker (Combined API over TCP or a pseudo-terminal), a
  Universal Robots controller (RTDE, dashboard, script and primary interfaces) and OpenIGTLink
  senders (PLUS, 3D Slicer, old senders), written from the public protocol descriptions and
  speaking the real wire protocols on loopback, behind one simulated ground truth in its own
  process (:class:`~spacecal.testing.fakes.client.WorldProcess`); and hostile peers that stall,
  drip or hang up. An integration of one's own (another client library, a station, a script)
  can be tested against them without hardware.
* :mod:`spacecal.testing.fuzz`: base input files for every command, mutations of them and of
  the options, and a runner that classifies what went wrong; the fuzz tests and
  ``benchmarks/fuzz.py`` share it.
* :mod:`spacecal.testing.disk_probe`: how long the disk stalls beside a run, which a bound on
  how fast a run ends leaves out (its recordings are synced before it ends);
  ``benchmarks/fsync_latency.py`` prints its distribution.

Nothing in the rest of the package imports this one (the layer contract in ``pyproject.toml``
puts it on top). Some fakes need the optional dependencies of the devices they stand in for
(the OpenIGTLink fake: crcmod, with the ``igtl`` extra); the fuzz tests' drawing needs
hypothesis.
"""

"""A fake world in its own process: one simulated ground truth behind fake devices that speak
the real wire protocols on loopback, so the real client libraries talk to them unmodified
(``--help`` lists every option)::

    python -m spacecal.testing.fakes.world --host 127.0.0.12 [--scenario paper-white] \
        [--igtl-port P] [--ndi-generation G] [--igtl-sender S] [--ur-generation G]

Prints ``READY {json}`` (ports, pty path) on stdout when every server listens; the NatNet
server (Motive, :mod:`spacecal.testing.fakes.natnet`) streams the marker and tools as rigid
bodies ``Marker``, ``Pointer`` and ``Reference`` from ``natnet_port``. A line
protocol on the control port injects faults and reads the truth::

    truth                      -> JSON of tracker_from_base, tcp_from_marker, home joints, and
                                  the further tools' definitions (pointer_from_tip, ...)
    phantom                    -> JSON of the phantom's truth: fiducials in image_lps and in the
                                  tracker, tracker_from_image_lps, planned paths
    pointer touch K            -> the pointer is held with its tip on fiducial K (1.. or F-K)
    pointer away               -> the pointer is put down out of view
    pointer sway MM            -> the hand holding the pointer sways by MM (0: holds still)
    occlude on|off             -> the marker is hidden from the tracker
    unplug                     -> the tracker stops answering / streaming
    stale                      -> the tracker keeps repeating its last frame
    protective_stop | emergency_stop | clear
    bump_marker DEG            -> the marker turns on the tool by DEG about its x axis
    move_tracker MM            -> the tracker moves by MM along its x axis
    (--rosbridge: a rosbridge server on ``rosbridge_port`` moves the same robot through a
    FollowJointTrajectory action and publishes its /joint_states: rosbridge.py)
    ur COMMAND [ARGS]          -> the UR controller: safety stops (safeguard_stop, safeguard_reset,
                                  fault, violation, ...), program_stop | program_pause, power_off,
                                  mode NAME, drop_rtde, remote_control on|off, registers_taken
                                  on|off, mark, stats (JSON); see FakeController.control in rtde.py
    received NAME              -> the last TRANSFORM a client sent under NAME (JSON), or NONE
    ndi FAULT ...              -> NDI tracker faults (see ``ndi_control``)
    igtl ...                   -> OpenIGTLink sender switches (see ``igtl_control``)
    quit
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import socket
import sys
import threading
import time

import numpy as np

from spacecal.geometry.transforms import axis_angle_transform, make_transform
from spacecal.sim.devices import RealClock, SimulatedRobot
from spacecal.sim.scenario import load_scenario
from spacecal.sim.world import build_world
from spacecal.testing.fakes import igtl, natnet, ndi, rosbridge, rtde
from spacecal.testing.fakes.net import accept_connections, listen


class FakeWorld:
    """The ground truth and the fault switches every fake device reads."""

    def __init__(self, scenario_name: str):
        self.world = build_world(load_scenario(scenario_name))
        self.clock = RealClock()
        # the robot's ticks are kept so a tracker can see the marker at its frame's own instant
        self.robot = SimulatedRobot(self.world, self.clock, stream_states=True)
        self._ticks: collections.deque = collections.deque(maxlen=2000)
        self.lock = threading.RLock()
        self.occluded = False
        self.unplugged = False
        self.stale = False
        self._last_frame: tuple | None = None
        # set by main() once the devices that read this world exist (declared here for the types)
        self.scenario_name: str
        self.igtl_sender: igtl.FakeIGTLSender
        self.received: dict[str, list]
        self.unplug_event: threading.Event
        self.ndi_faults: ndi.NDIFaults
        self.ndi_devices: tuple[ndi.FakeNDI, ...]
        self.controller: rtde.FakeController
        #: An OpenIGTLink sender (PLUS) stamps frames with its computer's clock: Unix time.
        self.igtl_epoch_s = time.time() - self.clock.now_s

    def _true_base_from_tcp(self, at_s: float) -> np.ndarray:
        """Where the TCP really was at ``at_s`` (a recent instant of the world's clock).

        A tracker's frame shows the marker at the frame's own instant, not at the moment a
        thread gets to compute it on a busy machine (0.1 ms to a scheduler slice later): the
        joints are interpolated between the controller ticks around ``at_s``, and past the
        newest tick towards where the arm is now. Taking the arm "now" instead lagged every
        frame by that wake-up delay, a jittering clock error no real tracker has."""
        states, now_s, joints_now = self.robot.drain_states_and_now()
        self._ticks.extend((state.time_s, state.joints_rad) for state in states)
        times = np.array([t for t, _ in self._ticks] + [now_s])
        joints = np.array([q for _, q in self._ticks] + [joints_now])
        keep = np.append(np.diff(times) > 0, True)  # the newest tick may be the present instant
        times, joints = times[keep], joints[keep]
        at = np.array([np.interp(at_s, times, joints[:, k]) for k in range(6)])
        return self.world.true_base_from_tcp(at[None])[0]

    def marker_frame(self, at_s: float | None = None):
        """(time_s, tracker_from_marker or None, rms_mm, spheres or None) at ``at_s`` (a recent
        instant; None: now), as the tracker sees it."""
        return self.frame(at_s)[:4]

    def frame(self, at_s: float | None = None):
        """:meth:`marker_frame` and, fifth, the further tools of the world in the same frame:
        {name: (tracker_from_<name> or None, rms_mm)} (``pointer``, ``reference``), each
        measured with the tracker's noise model."""
        with self.lock:
            if self.stale and self._last_frame is not None:
                return self._last_frame
            now = self.clock.now_s if at_s is None else at_s
            base_from_tcp = self._true_base_from_tcp(now)
            truth = self.world.tracker_from_base @ base_from_tcp @ self.world.tcp_from_marker
            tracked = self.world.track_marker(truth[None])
            pose = tracked.tracker_from_marker[0]
            seen = bool(np.all(np.isfinite(pose))) and not self.occluded
            tools = {}
            for name in self.world.tools:
                tool_truth = self.world.true_tool_pose(name, base_from_tcp, now)
                tool_pose, tool_rms = None, float("nan")
                if tool_truth is not None:
                    measured = self.world.track_tool(name, tool_truth[None])
                    if bool(np.all(np.isfinite(measured.tracker_from_marker[0]))):
                        tool_pose, tool_rms = measured.tracker_from_marker[0], float(measured.rms_mm[0])
                tools[name] = (tool_pose, tool_rms)
            frame = (
                now,
                pose if seen else None,
                float(tracked.rms_mm[0]) if seen else float("nan"),
                tracked.spheres_in_tracker[0] if seen else None,
                tools,
            )
            self._last_frame = frame
            return frame

    def truth(self) -> dict:
        return {
            # each tracker's clock minus the robot's (the controller's timestamp is the world's
            # clock): what spacecal's pairing offset ("robot clock minus tracker clock") should be,
            # negated
            "ndi_clock_minus_robot_clock_s": NDI_FRAMES_AT_START / self.world.tracker.rate_hz,
            "igtl_clock_minus_robot_clock_s": self.igtl_epoch_s,
            "natnet_clock_minus_robot_clock_s": NATNET_STARTED_BEFORE_S,
            "tracker_from_base": self.world.tracker_from_base.tolist(),
            "tcp_from_marker": self.world.tcp_from_marker.tolist(),
            "home_joints_rad": self.world.home_joints_rad.tolist(),
            "scenario": self.world.scenario.to_dict(),
            # the further tools: the pointer's calibrated tip (what a user knows) and its truth,
            # the guide's reference on the TCP and its own definition of the needle
            "pointer_from_tip": self.world.pointer_from_tip.tolist(),
            "pointer_from_tip_true": self.world.pointer_from_tip_true.tolist(),
            "tcp_from_reference": self.world.tcp_from_reference.tolist(),
            "reference_from_needle": self.world.reference_from_needle.tolist(),
        }


def free_port(host: str) -> int:
    with socket.socket() as probe:
        probe.bind((host, 0))
        return probe.getsockname()[1]


def serve_control(fake: FakeWorld, server, stop: threading.Event) -> None:
    for connection in accept_connections(server, stop):
        with connection, connection.makefile("rw") as stream:
            for line in stream:
                words = line.split()
                if not words:
                    continue
                command = words[0]
                reply = "OK"
                with fake.lock:
                    if command == "truth":
                        reply = json.dumps(fake.truth())
                    elif command == "occlude":
                        fake.occluded = words[1:] != ["off"]
                    elif command == "unplug":
                        fake.unplugged = True
                        fake.unplug_event.set()
                    elif command == "stale":
                        fake.stale = True
                    elif command in ("protective_stop", "emergency_stop"):
                        fake.robot._safety = command
                    elif command == "clear":  # the operator unlocks the stop on the pendant
                        fake.robot._safety = "normal"
                    elif command in ("bump_marker", "move_tracker"):
                        change_the_set_up(fake, command, float(words[1]))
                    elif command == "ur":
                        reply = fake.controller.control(words[1:])
                    elif command == "phantom":
                        reply = json.dumps(fake.world.phantom.to_dict())
                    elif command == "pointer":
                        reply = pointer_control(fake, words[1:])
                    elif command == "received":
                        matrix = getattr(fake, "received", {}).get(words[1])
                        reply = "NONE" if matrix is None else json.dumps(matrix)
                    elif command == "quit":
                        stop.set()
                    elif command in TRACKER_CONTROLS:
                        reply = TRACKER_CONTROLS[command](fake, words[1:])
                    else:
                        reply = f"ERROR unknown command {command}"
                stream.write(reply + "\n")
                stream.flush()


def change_the_set_up(fake: FakeWorld, change: str, amount: float) -> None:
    """What happens in an operating room between calibration and surgery: the marker is
    knocked on the tool (``bump_marker`` DEG) or the tracker's stand is pushed (``move_tracker`` MM)."""
    world = fake.world
    if change == "bump_marker":
        world.tcp_from_marker = world.tcp_from_marker @ axis_angle_transform(
            [1.0, 0.0, 0.0], np.radians(amount)
        )
    else:
        world.tracker_from_base = make_transform(np.eye(3), [amount, 0.0, 0.0]) @ world.tracker_from_base


def pointer_control(fake: FakeWorld, words: list[str]) -> str:
    """``touch K`` (the tip on fiducial K: its number from 1 or its label), ``away``, ``sway MM``."""
    world = fake.world
    try:
        if words[:1] == ["touch"] and len(words) == 2:
            which: int | str = int(words[1]) if words[1].isdigit() else words[1]
            world.place_pointer(which)
            return "OK " + str(world.pointer_fiducial)
        if words == ["away"]:
            world.put_pointer_away()
            return "OK"
        if words[:1] == ["sway"] and len(words) == 2:
            world.pointer_sway_mm = abs(float(words[1]))
            return "OK"
    except (ValueError, OSError) as exc:  # InvalidInputError, UnreachableError
        return f"ERROR {exc}"
    return "ERROR pointer touch K | pointer away | pointer sway MM"


# -- tracker fault switches (NDI generations and faults, OpenIGTLink senders) ----------------


def ndi_control(fake: FakeWorld, words: list[str]) -> str:
    """``ndi crc_error N`` | ``short_reply N`` | ``drop N`` (the next N BX/TX replies get a
    bad CRC, are cut short, or never come) | ``out_of_volume on|off`` | ``partial_volume on|off``
    | ``processing_exception on|off`` | ``interference on|off`` | ``disabled on|off`` |
    ``spoiled`` (how many replies were spoiled so far)."""
    return fake.ndi_faults.control(words)


def igtl_control(fake: FakeWorld, words: list[str]) -> str:
    """Switches of the OpenIGTLink sender (:mod:`spacecal.testing.fakes.igtl`)."""
    sender = getattr(fake, "igtl_sender", None)
    return "ERROR no OpenIGTLink sender" if sender is None else sender.control(words)


TRACKER_CONTROLS = {"ndi": ndi_control, "igtl": igtl_control}


#: The NDI frame counter counts camera frames since the tracker was switched on: here about
#: an hour before the robot controller's clock (the world's) started.
NDI_FRAMES_AT_START = 3600 * 60
#: Motive's timestamps count seconds since Motive started: here half an hour before the robot
#: controller's clock.
NATNET_STARTED_BEFORE_S = 1800.0
#: Motive's rigid bodies: the world's marker and further tools, by Motive-style names.
NATNET_BODIES = {"Marker": None, "Pointer": "pointer", "Reference": "reference"}


def start_motive(fake: FakeWorld, host: str, rate_hz: float) -> natnet.FakeMotive:
    """A NatNet server (Motive) streaming the world's marker and tools (:data:`NATNET_BODIES`),
    each frame the tracker's view at the frame's own instant; ``unplug`` stops its stream."""

    def poses(t_s: float) -> dict:
        _, marker, _, _, tools = fake.frame(at_s=t_s - NATNET_STARTED_BEFORE_S)
        found = {name: tools.get(tool, (None,))[0] for name, tool in NATNET_BODIES.items() if tool}
        return {"Marker": marker, **found}

    motive = natnet.FakeMotive(
        poses,
        tuple(NATNET_BODIES),
        rate_hz=rate_hz,
        host=host,
        clock=lambda: fake.clock.now_s + NATNET_STARTED_BEFORE_S,
    )

    def mute_when_unplugged() -> None:
        fake.unplug_event.wait()
        motive.set(mute=True)

    threading.Thread(target=mute_when_unplugged, name="natnet-unplug", daemon=True).start()
    return motive


def ndi_frame_source(fake: FakeWorld, rate_hz: float, stop: threading.Event):
    """Frames for the NDI fake as a real tracker makes them: captured at its own rate, each
    numbered by its capture instant on the tracker's own counter; a reply returns the newest
    captured frame (the pose at that frame's instant, not at the moment of the request)."""
    latest: dict[str, tuple] = {}

    def capture() -> None:
        while not stop.is_set():
            next_capture = (np.floor(fake.clock.now_s * rate_hz) + 1) / rate_hz
            time.sleep(max(0.0, next_capture - fake.clock.now_s))
            stamp, pose, rms, _, tools = fake.frame(at_s=next_capture)
            number = NDI_FRAMES_AT_START + int(round(stamp * rate_hz))
            further = {
                name: (tool, 0.0 if np.isnan(tool_rms) else tool_rms)
                for name, (tool, tool_rms) in tools.items()
            }
            latest["frame"] = (number, pose, (0.0 if np.isnan(rms) else rms), further)

    threading.Thread(target=capture, name="ndi-capture", daemon=True).start()

    def source():
        while "frame" not in latest:
            time.sleep(0.001)
        return latest["frame"]

    return source


# -- the UR controller's options ------------------------------------------------------------
def add_ur_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ur-generation", choices=sorted(rtde.GENERATIONS), default="cb3")
    parser.add_argument(
        "--calibrated-kinematics", action="store_true", help="the arm has factory-calibrated DH parameters"
    )
    parser.add_argument("--pendant-tcp", help="TCP set on the pendant: x,y,z (mm),rx,ry,rz (rad)")


def configure_ur(fake: FakeWorld, args: argparse.Namespace) -> None:
    fake.scenario_name = args.scenario
    tcp = [float(v) for v in args.pendant_tcp.split(",")] if args.pendant_tcp else None
    rtde.configure_world(fake, args.ur_generation, args.calibrated_kinematics, tcp)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--scenario", default="paper-white")
    parser.add_argument("--igtl-port", type=int, default=0)
    parser.add_argument("--ndi-log", action="store_true", help="log NDI commands to stderr")
    parser.add_argument("--ur-log", action="store_true", help="log UR controller traffic to stderr")
    parser.add_argument("--ndi-generation", default="vicra", choices=sorted(ndi.GENERATIONS))
    parser.add_argument("--igtl-sender", default="plus", choices=["plus", "slicer", "old"])
    parser.add_argument("--igtl-marker-name", default="MarkerToTracker")
    parser.add_argument(
        "--rosbridge", action="store_true", help="a rosbridge server driving the world's robot too"
    )
    parser.add_argument(
        "--niceness",
        type=int,
        help="run the world at this scheduling niceness (set before any thread starts, so every "
        "server thread has it; ignored where the caller may not raise it)",
    )
    add_ur_options(parser)
    args = parser.parse_args()
    if args.niceness is not None:
        with contextlib.suppress(OSError):  # a negative niceness needs the right to raise it
            os.setpriority(os.PRIO_PROCESS, 0, args.niceness)
    fake = FakeWorld(args.scenario)
    configure_ur(fake, args)
    stop = threading.Event()
    control_server = listen(args.host, 0)
    control_port = control_server.getsockname()[1]
    igtl_server = listen("127.0.0.1", args.igtl_port)
    igtl_port = igtl_server.getsockname()[1]
    fake.igtl_sender = igtl.FakeIGTLSender(fake, args.igtl_sender, args.igtl_marker_name)
    fake.received = fake.igtl_sender.received
    unplugged = threading.Event()
    fake.unplug_event = unplugged
    rate = fake.world.tracker.rate_hz
    log = sys.stderr if args.ndi_log else None
    fake.ndi_faults = ndi.NDIFaults()
    frames = ndi_frame_source(fake, rate, stop)
    # the tracker tells the tools apart by their geometry, as a real one does
    geometries = {"marker": fake.world.marker.spheres_in_marker}
    geometries |= {name: tool.spheres_in_marker for name, tool in fake.world.tools.items()}
    ndi_tcp = ndi.FakeNDI(frames, log, args.ndi_generation, fake.ndi_faults, geometries)
    ndi_serial = ndi.FakeNDI(frames, log, args.ndi_generation, fake.ndi_faults, geometries)
    fake.ndi_devices = (ndi_tcp, ndi_serial)  # "ur stats" says whether any is still tracking
    ndi_server = listen(args.host, 0)
    ndi_port = ndi_server.getsockname()[1]
    pty_master, pty_path = ndi.open_pty()
    threads = [
        threading.Thread(target=serve_control, args=(fake, control_server, stop), daemon=True),
        threading.Thread(
            target=fake.igtl_sender.serve, args=(igtl_server, stop, fake.world.tracker.rate_hz), daemon=True
        ),
        threading.Thread(target=ndi.serve_tcp, args=(ndi_tcp, ndi_server, stop, unplugged), daemon=True),
        threading.Thread(target=ndi.serve_pty, args=(ndi_serial, pty_master, stop, unplugged), daemon=True),
    ]
    for thread in threads:
        thread.start()
    fake.controller = rtde.start_controller(fake, args.host, stop, sys.stderr if args.ur_log else None)
    motive = start_motive(fake, args.host, rate)
    rosbridge_port = rosbridge.start_world_rosbridge(fake, args.host) if args.rosbridge else None
    time.sleep(0.3)
    print(
        "READY "
        + json.dumps(
            {
                "host": args.host,
                "control_port": control_port,
                "igtl_port": igtl_port,
                "ndi_port": ndi_port,
                "ndi_pty": pty_path,
                "natnet_port": motive.port,
                "rosbridge_port": rosbridge_port,
            }
        ),
        flush=True,
    )

    # Die with the parent: the test process holds our stdin; EOF means it is gone.
    def stop_at_end_of_input() -> None:
        sys.stdin.read()
        stop.set()

    threading.Thread(target=stop_at_end_of_input, daemon=True).start()
    stop.wait()


if __name__ == "__main__":
    main()

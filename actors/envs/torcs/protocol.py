"""Lockstep driving of one TORCS process from Python (issue 15, stage 2).

TORCS runs a race file in results-only mode (``torcs-bin -r race.xml``: no window, no menus, not
paced in real time). Our robot (robot/gvfdrive.cpp) drives the only car. Every 0.1 s of simulated
time (5 robot calls at TORCS's 50 Hz) it writes the car's state into a pipe and blocks until Python
writes the action back; it holds that action for the next 5 calls. So the simulation advances
exactly one control step per ``step()`` and never runs ahead of Python.

    with TorcsProcess() as torcs:
        state = torcs.reset(RaceSpec("g-track-1", "road", start=100.0))
        while ...:
            state = torcs.step(steer=0.0, target_speed=15.0)  # state.time grows by 0.1 s

Wire format: two pipes inherited by TORCS (environment ``GVF_TORCS_FDS="in,out"`` names them for
the robot), fixed-size little-endian messages. ``STATE`` (robot -> Python): magic 'GVFS', version,
then the fields of ``CarState`` in order. ``ACTION`` (Python -> robot): magic 'GVFA', command
(0 drive, 1 quit), steer in [-1, 1] (+ turns left), target speed in m/s (the robot's speed
controller chooses throttle, brake and gear). The C side is the struct GvfState in gvfdrive.cpp.

Reset relaunches TORCS with a new race file (10-45 ms on this machine, depending on the road), which
also bounds any leak inside TORCS to one episode. A TORCS that dies, hangs past ``step_timeout`` or
speaks out of step is killed and relaunched on the same race; ``step()`` then returns the fresh
race's first state (``step == 0``), which the caller treats as the end of the episode.
"""

from __future__ import annotations

import logging
import os
import select
import shutil
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, Protocol

from actors.envs.torcs.race import RaceSpec, race_xml, raceengine_xml

log = logging.getLogger(__name__)

STEP_SECONDS = 0.1
"""Simulated time of one control step: 5 robot calls of 0.02 s."""

STATE_MAGIC = 0x53465647  # b"GVFS" little-endian
ACTION_MAGIC = 0x41465647  # b"GVFA" little-endian
PROTOCOL_VERSION = 1
COMMAND_DRIVE, COMMAND_QUIT = 0, 1

STATE = struct.Struct("<IIQ" + "d" * 21 + "i" * 6)
ACTION = struct.Struct("<IIdd")
assert STATE.size == 208 and ACTION.size == 24  # the C side static_asserts the same sizes


class CarState(NamedTuple):
    """One state from the robot, in the order of the wire (see gvfdrive.cpp's GvfState)."""

    step: int  # control steps since this race started (0: the first state of a race)
    time: float  # simulated race time, s
    x: float  # position, m (track frame)
    y: float
    z: float
    yaw: float  # heading, rad, [0, 2 pi)
    speed: float  # longitudinal speed, m/s
    speed_lateral: float  # m/s, + left
    yaw_rate: float  # rad/s
    to_middle: float  # distance from the road's middle, m, + left (TORCS's toMiddle)
    to_left: float  # distance to the left edge, m (negative outside)
    to_right: float  # distance to the right edge, m
    angle: float  # road direction minus yaw, rad, [-pi, pi)
    dist_from_start: float  # distance along the road from the start line, m
    dist_raced: float  # TORCS's distRaced, m (negative until the start line is first crossed)
    track_length: float  # m
    seg_curvature: float  # signed curvature of the current segment, 1/m, + left
    seg_width: float  # road width, m
    steer: float  # steering held over the step that led here (the action sent)
    target_speed: float  # target speed held over that step, m/s
    accel: float  # throttle at the robot's last call, [0, 1]
    brake: float  # brake at the robot's last call, [0, 1]
    seg_id: int  # TORCS's segment number
    seg_type: int  # 1 right turn, 2 left turn, 3 straight
    lap: int  # start-line crossings so far (TORCS's laps; 0 until the first one)
    damage: int  # TORCS's damage points
    gear: int
    state: int  # TORCS's RM_CAR_STATE_* flags


def decode_state(data: bytes) -> CarState:
    """A state message as ``CarState``; ``TorcsError`` if it is not one of this protocol's."""
    magic, version, *fields = STATE.unpack(data)
    if magic != STATE_MAGIC or version != PROTOCOL_VERSION:
        raise TorcsError(f"not a version-{PROTOCOL_VERSION} state (magic {magic:#x}, version {version})")
    return CarState(*fields)


def encode_action(steer: float, target_speed: float, command: int = COMMAND_DRIVE) -> bytes:
    return ACTION.pack(ACTION_MAGIC, command, float(steer), float(target_speed))


class TorcsError(RuntimeError):
    """TORCS did not start, or kept failing after relaunches."""


class Launcher(Protocol):
    """How to start a TORCS (or a stand-in speaking the robot's side of the protocol)."""

    def launch_args(self, race_file: Path, local_dir: Path) -> tuple[list[str], Path, dict[str, str]]:
        """argv, working directory and extra environment for a race file and a local config dir."""
        ...


def default_prefix() -> Path:
    """Where ``make torcs`` installs: $GVF_TORCS_PREFIX, else third_party/torcs in the repository."""
    env = os.environ.get("GVF_TORCS_PREFIX")
    return Path(env) if env else Path(__file__).resolve().parents[3] / "third_party" / "torcs"


@dataclass(frozen=True)
class TorcsInstall:
    """A TORCS installed by ``make torcs``: the binary, modules and robots, and the data dir."""

    prefix: Path

    @property
    def lib_dir(self) -> Path:
        return self.prefix / "lib" / "torcs"

    @property
    def data_dir(self) -> Path:
        return self.prefix / "share" / "games" / "torcs"

    @property
    def binary(self) -> Path:
        return self.lib_dir / "torcs-bin"

    def missing(self) -> list[Path]:
        """The files a lockstep race needs that are not there (empty when the install is complete)."""
        needed = [
            self.binary,
            self.lib_dir / "drivers" / "gvfdrive" / "gvfdrive.so",
            self.data_dir / "drivers" / "gvfdrive" / "gvfdrive.xml",
            self.data_dir / "tracks",
            self.data_dir / "cars",
        ]
        return [p for p in needed if not p.exists()]

    def launch_args(self, race_file: Path, local_dir: Path) -> tuple[list[str], Path, dict[str, str]]:
        # TORCS opens cars/, tracks/ and categories/ relative to its working directory: the data dir.
        argv = [str(self.binary), "-l", str(local_dir), "-L", str(self.lib_dir), "-D", str(self.data_dir)]
        argv += ["-r", str(race_file)]
        lib_path = str(self.lib_dir / "lib")
        old = os.environ.get("LD_LIBRARY_PATH")
        return argv, self.data_dir, {"LD_LIBRARY_PATH": f"{lib_path}:{old}" if old else lib_path}


def find_install(prefix: Path | None = None) -> TorcsInstall | None:
    """The install under ``prefix`` (default: ``default_prefix()``), or None if ``make torcs`` has not run."""
    install = TorcsInstall(prefix or default_prefix())
    return None if install.missing() else install


class TorcsProcess:
    """One TORCS process stepped in lockstep: ``reset`` (re)launches a race, ``step`` advances 0.1 s.

    ``launches`` counts every start of TORCS, ``relaunches`` those that replaced a TORCS that died,
    hung or spoke out of step.
    """

    def __init__(
        self,
        launcher: Launcher | None = None,
        *,
        workdir: Path | None = None,
        start_timeout: float = 30.0,
        step_timeout: float = 10.0,
        max_attempts: int = 3,
    ) -> None:
        if launcher is None:
            launcher = find_install()
            if launcher is None:
                raise TorcsError(f"no TORCS under {default_prefix()}: run `make torcs`")
        self.launcher = launcher
        self.start_timeout = start_timeout
        self.step_timeout = step_timeout
        self.max_attempts = max_attempts
        self._own_workdir = workdir is None
        # One folder a process: the race file, TORCS's local config (results land there) and its log.
        self.workdir = Path(tempfile.mkdtemp(prefix="gvf-torcs-")) if workdir is None else Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.spec: RaceSpec | None = None
        self.proc: subprocess.Popen | None = None
        self._to_robot = -1
        self._from_robot = -1
        self._send_error: OSError | None = None
        self.launches = 0
        self.relaunches = 0

    # -- public API --------------------------------------------------------------------------

    def reset(self, spec: RaceSpec) -> CarState:
        """Start a fresh race for ``spec`` and return its first state (``step == 0``)."""
        self.spec = spec
        return self._launch_with_retries()

    def step(self, steer: float, target_speed: float) -> CarState:
        """Send the action, let TORCS simulate 0.1 s, return the new state.

        If TORCS died, hung or answered out of step, it is relaunched on the same race and the
        fresh race's first state (``step == 0``) is returned instead.
        """
        self.send(steer, target_speed)
        return self.receive()

    def send(self, steer: float, target_speed: float) -> None:
        """The first half of ``step``: several processes are sent their actions first, then each is
        read with ``receive``, so their TORCS simulate at the same time (TorcsDrive's vector env)."""
        if self.proc is None:
            raise RuntimeError("step() before reset()")
        try:
            self._write(encode_action(steer, target_speed))
        except OSError as e:
            self._send_error = e  # a dead TORCS: reported and relaunched by receive()

    def receive(self) -> CarState:
        """The second half of ``step``: the state after the action that ``send`` wrote."""
        if self.proc is None:
            raise RuntimeError("receive() before reset()")
        try:
            if self._send_error is not None:
                raise self._send_error
            return self._read_state(self.step_timeout)
        except (OSError, TorcsError) as e:
            self._send_error = None
            self.relaunches += 1
            log.warning("TORCS (pid %s) failed a step (%s); relaunching: %s", self.proc.pid, e, self._log_tail())
            return self._launch_with_retries()

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def close(self) -> None:
        self._stop()
        if self._own_workdir:
            shutil.rmtree(self.workdir, ignore_errors=True)

    def __enter__(self) -> TorcsProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- launching ----------------------------------------------------------------------------

    def _launch_with_retries(self) -> CarState:
        assert self.spec is not None
        error: Exception | None = None
        for _ in range(self.max_attempts):
            try:
                return self._launch(self.spec)
            except (OSError, TorcsError) as e:
                error = e
                log.warning("TORCS did not start (%s): %s", e, self._log_tail())
        raise TorcsError(f"TORCS failed to start {self.max_attempts} times: {error}; log: {self._log_tail()}")

    def _launch(self, spec: RaceSpec) -> CarState:
        self._stop()
        self._send_error = None
        race_file = self.workdir / "gvf-practice.xml"
        race_file.write_text(race_xml(spec, name="gvf-practice"))
        local_dir = self.workdir / "local"
        (local_dir / "config").mkdir(parents=True, exist_ok=True)
        (local_dir / "config" / "raceengine.xml").write_text(raceengine_xml())
        # TORCS writes a results file per race: dropping them keeps the disk flat over many episodes.
        shutil.rmtree(local_dir / "results", ignore_errors=True)
        argv, cwd, extra_env = self.launcher.launch_args(race_file, local_dir)
        robot_in, to_robot = os.pipe()
        from_robot, robot_out = os.pipe()
        env = {**os.environ, **extra_env, "GVF_TORCS_FDS": f"{robot_in},{robot_out}"}
        try:
            with open(self.workdir / "torcs.log", "wb") as log_file:
                self.proc = subprocess.Popen(
                    argv,
                    cwd=cwd,
                    env=env,
                    stdin=subprocess.DEVNULL,
                    stdout=log_file,
                    stderr=subprocess.STDOUT,
                    pass_fds=(robot_in, robot_out),
                    start_new_session=True,  # a Ctrl-C meant for Python must not kill TORCS mid-message
                )
        except BaseException:
            for fd in (robot_in, to_robot, from_robot, robot_out):
                os.close(fd)
            raise
        # Only TORCS holds the robot's ends now, so its death shows here as end of file.
        os.close(robot_in)
        os.close(robot_out)
        self._to_robot, self._from_robot = to_robot, from_robot
        self.launches += 1
        state = self._read_state(self.start_timeout)
        if state.step != 0:
            raise TorcsError(f"a fresh race began at step {state.step}")
        return state

    def _stop(self) -> None:
        """Close the pipes (the robot exits on end of file), then make sure the process is gone."""
        for fd in (self._to_robot, self._from_robot):
            if fd >= 0:
                os.close(fd)
        self._to_robot = self._from_robot = -1
        if self.proc is not None:
            try:
                self.proc.wait(timeout=2.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            self.proc = None

    # -- pipe I/O -----------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        # Messages are far below PIPE_BUF, so one write is atomic and never partial.
        os.write(self._to_robot, data)

    def _read_state(self, timeout: float) -> CarState:
        deadline = time.monotonic() + timeout
        chunks: list[bytes] = []
        need = STATE.size
        while need > 0:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or not select.select([self._from_robot], [], [], remaining)[0]:
                self._kill()
                raise TorcsError(f"no state within {timeout:.1f} s")
            chunk = os.read(self._from_robot, need)
            if not chunk:
                code = self.proc.wait() if self.proc is not None else None
                raise TorcsError(f"TORCS exited (code {code})")
            chunks.append(chunk)
            need -= len(chunk)
        return decode_state(b"".join(chunks))

    def _kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def _log_tail(self, lines: int = 5) -> str:
        try:
            text = (self.workdir / "torcs.log").read_text(errors="replace")
        except OSError:
            return "(no log)"
        return " | ".join(text.strip().splitlines()[-lines:])

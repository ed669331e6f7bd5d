"""A laser positioner driven by a GRBL-style G-code controller over a serial line.

Two kinematics are provided (``docs/scanning.md``, "Positioner model"):

* :class:`PanTiltHead`: a pan-tilt unit at a fixed station; controller axis ``X`` is the pan and
  ``Y`` the tilt, both in degrees (set GRBL's steps/mm to steps/degree);
* :class:`Gantry`: a laser pointing along a fixed direction, carried in a plane; ``X`` and ``Y``
  are the carriage position in millimetres.

Protocol (GRBL 1.1): every line is answered by ``ok`` or ``error:N``; ``?`` (real-time, no line
ending) returns ``<Idle|...>`` / ``<Run|...>``; Ctrl-X soft-resets and the controller greets with
``Grbl ...``. ``move_to`` sends ``G0`` and then polls ``?`` until the machine is idle, so it returns
when the beam is there. A controller that stops answering is reconnected once (port reopened,
soft reset, ``$X`` unlock) and the command is sent again; a second silence stops the scan.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.checks import check_matrix
from scanrig.scan.protocol import Beam, RigError
from scanrig.scan.serial_line import SerialLine

#: GRBL 1.1 error codes a positioner is likely to meet (the full table is in GRBL's docs).
GRBL_ERRORS = {
    1: "G-code words consist of a letter and a value",
    2: "numeric value format is not valid",
    9: "G-code locked out during alarm or jog state",
    15: "jog target exceeds machine travel",
    20: "unsupported or invalid G-code command",
}
#: Largest distance between a beam's origin and the pan-tilt pivot, metres (round-off only).
ORIGIN_TOL_M = 1e-6
#: Largest angle between a gantry beam and the gantry's fixed direction, radians.
DIRECTION_TOL_RAD = 1e-6


class PositionerError(RigError):
    """The positioner refused a command, or its controller stopped answering."""


@dataclass(frozen=True)
class PanTiltHead:
    """A pan-tilt unit at a fixed station.

    Parameters
    ----------
    origin_m : (3,) float
        Pivot of the head, world frame, metres (every beam starts here).
    world_from_head : (3, 3) float, optional
        Rotation of the head's base frame (pan about its z, tilt = elevation above its xy plane).
    """

    origin_m: np.ndarray
    world_from_head: np.ndarray = field(default_factory=lambda: np.eye(3))

    def axes(self, beam: Beam) -> dict[str, float]:
        """Controller axes for a beam: ``{"X": pan_deg, "Y": tilt_deg}``."""
        origin = check_matrix(self.origin_m, (3,), "pan-tilt origin_m")
        if np.linalg.norm(beam.origin - origin) > ORIGIN_TOL_M:
            raise InputError(f"beam origin {beam.origin.tolist()} is not the pan-tilt pivot {origin.tolist()}")
        d = np.asarray(self.world_from_head).T @ beam.direction
        return {"X": float(np.degrees(np.arctan2(d[1], d[0]))),
                "Y": float(np.degrees(np.arcsin(np.clip(d[2], -1.0, 1.0))))}


@dataclass(frozen=True)
class Gantry:
    """A laser carried in the plane ``z = height_m`` (world), always pointing along ``direction``.

    Parameters
    ----------
    height_m : float
        Height of the carriage plane, metres.
    direction : (3,) float
        The fixed unit beam direction, default straight down.
    """

    height_m: float
    direction: tuple[float, float, float] = (0.0, 0.0, -1.0)

    def axes(self, beam: Beam) -> dict[str, float]:
        """Controller axes for a beam: ``{"X": x_mm, "Y": y_mm}`` of the carriage."""
        if abs(beam.origin[2] - self.height_m) > ORIGIN_TOL_M:
            raise InputError(f"beam origin z {beam.origin[2]} is not on the gantry plane z = {self.height_m}")
        if np.arccos(np.clip(beam.direction @ np.asarray(self.direction), -1, 1)) > DIRECTION_TOL_RAD:
            raise InputError(f"gantry beams point along {list(self.direction)}, got {beam.direction.tolist()}")
        return {"X": float(beam.origin[0] * 1e3), "Y": float(beam.origin[1] * 1e3)}


class GcodePositioner:
    """GRBL-style controller on a serial line; implements the ``LaserPositioner`` protocol.

    Parameters
    ----------
    port : str
        Serial device path.
    kinematics : PanTiltHead or Gantry
        Converts a beam into controller axes.
    baud : int
        Line speed.
    reply_timeout_s : float
        Longest wait for ``ok`` / ``error:N`` / a status report.
    move_timeout_s : float
        Longest wait for a move to finish (status back to ``Idle``).
    laser_on, laser_off : str
        G-code lines that switch the laser (GRBL laser mode: spindle PWM).
    """

    def __init__(self, port: str, kinematics, baud: int = 115200, reply_timeout_s: float = 2.0,
                 move_timeout_s: float = 60.0, laser_on: str = "M3 S1000", laser_off: str = "M5"):
        self.port, self.kinematics, self.baud = port, kinematics, baud
        self.reply_timeout_s, self.move_timeout_s = reply_timeout_s, move_timeout_s
        self.laser_on, self.laser_off = laser_on, laser_off
        self.n_reconnects = 0
        self._line: SerialLine | None = None
        self._connect()

    # --- the protocol ---------------------------------------------------------------------------
    def move_to(self, beam: Beam) -> None:
        """Rapid move to the beam's axes, then wait until the controller reports ``Idle``."""
        axes = self.kinematics.axes(beam)
        self.command("G0 " + " ".join(f"{k}{v:.4f}" for k, v in axes.items()))
        self.wait_idle()

    def set_laser(self, on: bool) -> None:
        """Switch the laser with ``laser_on`` / ``laser_off``."""
        self.command(self.laser_on if on else self.laser_off)

    # --- controller I/O -----------------------------------------------------------------------
    def command(self, line: str) -> None:
        """Send one G-code line and wait for ``ok``; reconnect once if the controller is silent.

        Raises
        ------
        PositionerError
            On ``error:N`` / ``ALARM:N``, or when the controller stays silent after a reconnect.
        """
        reply = self._send(line)
        if reply is None:
            self._reconnect()
            reply = self._send(line)
        if reply is None:
            raise PositionerError(f"{self.port}: no reply to {line!r} within {self.reply_timeout_s:g} s, "
                                  f"even after reconnecting")
        if reply != "ok":
            raise PositionerError(f"{self.port}: {line!r} refused with {_explain(reply)}")

    def status(self) -> str:
        """The controller's status report, e.g. ``<Idle|MPos:0.000,0.000,0.000|FS:0,0>``."""
        self._line.write(b"?")
        reply = self._reply(("<",))
        if reply is None:
            raise PositionerError(f"{self.port}: no status report within {self.reply_timeout_s:g} s")
        return reply

    def wait_idle(self) -> None:
        """Poll ``?`` until the machine is ``Idle`` (an ``Alarm`` state is an error)."""
        deadline = time.monotonic() + self.move_timeout_s
        while time.monotonic() < deadline:
            state = self.status()[1:].split("|", 1)[0]
            if state == "Idle":
                return
            if state.startswith("Alarm"):
                raise PositionerError(f"{self.port}: controller in alarm state ({state}); clear it and resume")
            time.sleep(0.01)
        raise PositionerError(f"{self.port}: move not finished within {self.move_timeout_s:g} s")

    def close(self) -> None:
        if self._line is not None:
            self._line.close()
            self._line = None

    def _reply(self, prefixes: tuple[str, ...]) -> str | None:
        """First line starting with one of ``prefixes``; other lines (``[MSG:..]``, banners) are skipped."""
        deadline = time.monotonic() + self.reply_timeout_s
        while (left := deadline - time.monotonic()) > 0:
            line = self._line.readline(left)
            if line is None:
                return None
            if line.startswith(prefixes):
                return line
        return None

    def _send(self, line: str) -> str | None:
        """One line out, its ``ok`` / ``error:N`` / ``ALARM:N`` back; ``None`` if silent or disconnected."""
        try:
            self._line.write(line.encode("ascii") + b"\n")
            return self._reply(("ok", "error:", "ALARM:"))
        except OSError:
            return None

    def _connect(self) -> None:
        try:
            self._line = SerialLine(self.port, self.baud)
        except OSError as exc:
            raise PositionerError(f"{self.port}: cannot open the serial port: {exc}") from exc
        self._line.write(b"\x18")                              # soft reset: known state, greeting
        if self._reply(("Grbl",)) is None:
            self.close()
            raise PositionerError(f"{self.port}: no GRBL greeting within {self.reply_timeout_s:g} s after a reset "
                                  f"(wrong port or baud rate?)")
        self._line.discard_input()

    def _reconnect(self) -> None:
        self.close()
        self._connect()
        self.n_reconnects += 1
        if self._send("$X") != "ok":                            # a reset leaves GRBL locked
            raise PositionerError(f"{self.port}: cannot unlock the controller ($X) after reconnecting")


def _explain(reply: str) -> str:
    kind, _, code = reply.partition(":")
    meaning = GRBL_ERRORS.get(int(code)) if kind == "error" and code.isdigit() else None
    return f"{reply} ({meaning})" if meaning else reply

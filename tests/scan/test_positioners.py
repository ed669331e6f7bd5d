"""G-code positioner against a fake GRBL controller on a pseudo-terminal; kinematics properties."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanrig.errors import InputError
from scanrig.scan.positioners import Gantry, GcodePositioner, PanTiltHead, PositionerError
from scanrig.scan.protocol import Beam
from tests.scan.fake_grbl import FakeGrbl

#: Reply timeout for the fake controller: it answers in microseconds (milliseconds on a loaded
#: machine), so 1 s only matters when it is told to stay silent.
TIMEOUT_S = 1.0
HEAD = PanTiltHead(np.array([0.0, 0.0, 0.5]))


def _beam(pan_deg, tilt_deg, origin=(0.0, 0.0, 0.5)):
    p, t = np.radians(pan_deg), np.radians(tilt_deg)
    return Beam(np.array(origin), np.array([np.cos(t) * np.cos(p), np.cos(t) * np.sin(p), np.sin(t)]))


@pytest.fixture
def grbl():
    fake = FakeGrbl()
    yield fake
    fake.close()


@pytest.fixture
def positioner(grbl):
    pos = GcodePositioner(grbl.path, HEAD, reply_timeout_s=TIMEOUT_S, move_timeout_s=2.0)
    yield pos
    pos.close()


def test_move_waits_until_idle_and_switches_laser(grbl, positioner):
    positioner.set_laser(True)
    positioner.move_to(_beam(45.0, -30.0))
    positioner.set_laser(False)
    assert grbl.lines == ["M3 S1000", "G0 X45.0000 Y-30.0000", "M5"]
    assert grbl.position == (45.0, -30.0)
    assert grbl._running == 0                      # returned only after the Run reports were consumed
    assert grbl.resets == 1 and positioner.n_reconnects == 0


def test_error_reply_is_a_clear_error(grbl, positioner):
    grbl.refuse["G0"] = 15
    with pytest.raises(PositionerError, match=r"'G0 X10.0000 Y-60.0000' refused with error:15 \(jog target exceeds machine travel\)"):
        positioner.move_to(_beam(10.0, -60.0))


def test_silent_controller_is_reconnected_and_the_command_resent(grbl, positioner):
    grbl.silent_lines = 1
    positioner.move_to(_beam(-20.0, -45.0))
    assert positioner.n_reconnects == 1
    assert grbl.resets == 2
    assert grbl.lines == ["G0 X-20.0000 Y-45.0000", "$X", "G0 X-20.0000 Y-45.0000"]
    assert grbl.position == (-20.0, -45.0)


def test_controller_that_stays_silent(grbl, positioner):
    grbl.silent_lines = 10
    with pytest.raises(PositionerError, match=r"cannot unlock the controller \(\$X\) after reconnecting"):
        positioner.set_laser(True)


def test_controller_that_ignores_the_reset(grbl):
    grbl.deaf = True
    with pytest.raises(PositionerError, match=r"no GRBL greeting within 1 s after a reset \(wrong port or baud rate\?\)"):
        GcodePositioner(grbl.path, HEAD, reply_timeout_s=TIMEOUT_S)


def test_alarm_state_stops_the_move(grbl, positioner):
    grbl.alarm = True
    with pytest.raises(PositionerError, match=r"controller in alarm state \(Alarm\); clear it and resume"):
        positioner.move_to(_beam(0.0, -90.0))


def test_missing_port(tmp_path):
    with pytest.raises(PositionerError, match=r"ttyNOPE: cannot open the serial port: \[Errno 2\]"):
        GcodePositioner(str(tmp_path / "ttyNOPE"), HEAD)


def test_bad_baud(grbl):
    with pytest.raises(InputError, match=r"baud must be a standard serial speed \(e.g. 115200\), got 12345"):
        GcodePositioner(grbl.path, HEAD, baud=12345)


@settings(max_examples=60, deadline=None)
@given(st.floats(-179.0, 179.0), st.floats(-89.0, 89.0))
def test_pan_tilt_axes_invert_the_beam(pan_deg, tilt_deg):
    rot = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])     # head turned 90 deg
    head = PanTiltHead(np.zeros(3), rot)
    beam = _beam(pan_deg, tilt_deg, origin=(0.0, 0.0, 0.0))
    axes = head.axes(Beam(beam.origin, rot @ beam.direction))
    # float64 trigonometry round trip of unit vectors: ~1e-13 degrees; 1e-9 leaves margin
    np.testing.assert_allclose([axes["X"], axes["Y"]], [pan_deg, tilt_deg], atol=1e-9)


def test_pan_tilt_refuses_a_beam_from_elsewhere():
    with pytest.raises(InputError, match=r"beam origin \[0.0, 0.0, 0.4\] is not the pan-tilt pivot \[0.0, 0.0, 0.5\]"):
        HEAD.axes(_beam(0.0, -90.0, origin=(0.0, 0.0, 0.4)))


def test_gantry_axes_and_refusals():
    gantry = Gantry(0.4)
    down = np.array([0.0, 0.0, -1.0])
    assert gantry.axes(Beam(np.array([0.012, -0.5, 0.4]), down)) == {"X": 12.0, "Y": -500.0}
    with pytest.raises(InputError, match=r"gantry beams point along \[0.0, 0.0, -1.0\]"):
        gantry.axes(_beam(0.0, -80.0, origin=(0.0, 0.0, 0.4)))
    with pytest.raises(InputError, match=r"beam origin z 0.3 is not on the gantry plane z = 0.4"):
        gantry.axes(Beam(np.array([0.0, 0.0, 0.3]), down))

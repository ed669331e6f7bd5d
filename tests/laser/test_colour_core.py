"""A laser of another colour whose beam turns white in its core, and one too dim to reach half the
clip level: the library's colour check names it (scanrig.laser.colour_check)."""

import dataclasses
from types import SimpleNamespace

import numpy as np
import pyarrow as pa
import pytest

from scanrig.errors import InputError
from scanrig.io.session import read_image
from scanrig.laser.colour_check import clipped_candidates
from scanrig.laser.spots import detect_spots
from scanrig.laser.stripes import detect_stripe
from tests.data_paths import real_data
from tests.laser.colour_synth import RESPONSE, spot_frames, stripe_frames

#: The rendered camera with a green laser (its crosstalk into red and blue as the red laser's).
GREEN_LASER = dataclasses.replace(RESPONSE, laser_rgb=(0.07, 1.0, 0.05))


def _named(asked: str, shown: str) -> str:
    """The check's error for ``asked`` on a frame whose laser is ``shown``, as a regular expression."""
    swapped = r" \(red and blue are swapped where RGB data were stored as BGR\)" if {asked, shown} == {
        "red", "blue"} else ""
    return (rf"^color='{asked}': (no {asked} laser in this frame|{asked} finds \d+ times less laser light than "
            rf"{shown} in this frame); its {shown} channel shows one \(\d+ DN of laser light\): use "
            rf"color='{shown}'{swapped}$")


# --- which clipped candidates are another colour's white core ----------------------------------


def _two_beams() -> np.ndarray:
    """A frame (40 x 60 x 3 uint8) crossed by two vertical beams on grey paper: a red one clipped
    in red over columns 10-19 and in green over 14-15 (its white core), and a green one clipped in
    green over columns 40-49 and in red over 44-45."""
    image = np.full((40, 60, 3), 150, np.uint8)
    image[:, 10:20, 0] = image[:, 14:16, 1] = 255
    image[:, 40:50, 1] = image[:, 44:46, 0] = 255
    return image


def _signal(image: np.ndarray, channel: int, origin=(0, 0), seed_floor=None) -> SimpleNamespace:
    """``image`` as the check reads a LaserImage of the colour of ``channel``."""
    colour = SimpleNamespace(image=image, clip_level=np.full(3, 247.35), laser_channel=channel)
    return SimpleNamespace(origin=origin, colour=colour, seed_floor=seed_floor)


def _candidates(u, saturated, v=20.0) -> pa.Table:
    u = np.asarray(u, float)
    return pa.table({"u": u, "v": np.full(u.size, v), "saturated": np.asarray(saturated)})


def test_a_clipped_run_inside_a_wider_one_of_another_channel_is_its_white_core():
    """Green on the red beam's core is red's light; green on its own beam, and red on its own,
    are their own light past full scale; red inside the green beam's band is green's."""
    image = _two_beams()
    green = clipped_candidates(_signal(image, 1), _candidates([14.6, 44.5, 30.0, 14.6], [True, True, True, False]))
    np.testing.assert_array_equal(green.cores, [True, False, False, False])  # 30: green not clipped;
    np.testing.assert_array_equal(green.own, [False, True, False, False])  # last: not flagged saturated
    red = clipped_candidates(_signal(image, 0), _candidates([14.6, 44.5], [True, True]))
    np.testing.assert_array_equal(red.own, [True, False])
    np.testing.assert_array_equal(red.cores, [False, True])


def test_runs_that_end_alike_are_neither_light_nor_core():
    """A glint that clips red and green over the same columns is neither colour's light past full
    scale nor a core: one run must reach beyond the other on both sides, across the beam (rows
    here: the runs along the column are as long as the frame)."""
    image = _two_beams()
    image[:, 10:20, 0] = 150
    image[:, 12:18, 0] = image[:, 12:18, 1] = 255
    for channel in (0, 1):
        clipped = clipped_candidates(_signal(image, channel), _candidates([14.6], [True]))
        assert clipped.own.tolist() == clipped.cores.tolist() == [False]
    image[:, 12, 1] = 150  # green one pixel shorter on the left only
    for channel in (0, 1):
        clipped = clipped_candidates(_signal(image, channel), _candidates([14.6], [True]))
        assert clipped.own.tolist() == clipped.cores.tolist() == [False]
    image[:, 17, 1] = 150  # and on the right: red's light, green inside its core
    red, green = (clipped_candidates(_signal(image, c), _candidates([14.6], [True])) for c in (0, 1))
    assert red.own.tolist() == green.cores.tolist() == [True]


def test_runs_are_read_in_the_frame_of_the_region_of_interest():
    green = clipped_candidates(_signal(_two_beams(), 1, origin=(100, 7)), _candidates([114.6], [True], v=27.0))
    assert green.cores.tolist() == [True]


def test_where_the_scene_reaches_the_clip_level_no_clipped_candidate_counts():
    """A cell whose scene is at the clip level (seed floor above 0): its clipped pixels are the
    scene's, neither light past full scale nor a beam's white core."""
    from scanrig.laser.background import BG_CELL

    seed_floor = np.zeros((-(-40 // BG_CELL), -(-60 // BG_CELL)), np.float32)
    seed_floor[20 // BG_CELL, 15 // BG_CELL] = 120.0  # the red beam's core at row 20; not the green beam's
    candidates = _candidates([14.6, 44.5], [True, True])
    green = clipped_candidates(_signal(_two_beams(), 1, seed_floor=seed_floor), candidates)
    assert green.cores.tolist() == [False, False] and green.own.tolist() == [False, True]


# --- the rendered over-exposed stripes --------------------------------------------------------


@pytest.fixture(scope="module", params=[1.0, 3.0, 8.0], ids=["1x", "3x", "8x"])
def red_stripe(request):
    """An over-exposed red stripe on printed paper (480 x 640) and its laser-off frame."""
    return stripe_frames(np.random.default_rng(0), overexposure=request.param)[:2]


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize("asked", ["green", "blue"])
def test_another_colour_asked_of_the_red_stripe_names_red(red_stripe, asked, dark):
    """Before, only blue at 8 x full scale raised: green clips in the beam's white core there
    (the red laser's light, which dips_more_than_rises does not see), and at 1 and 3 x red's
    fitted peaks, 85-112 DN above the paper, stay below half the clip level (124 DN), so red
    found no laser light to name."""
    on, off = red_stripe
    with pytest.raises(InputError, match=_named(asked, "red")):
        detect_stripe(on, color=asked, dark=off if dark else None)


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
def test_red_asked_of_the_red_stripe_is_returned(red_stripe, dark):
    on, off = red_stripe
    assert len(detect_stripe(on, color="red", dark=off if dark else None)) > 0


@pytest.mark.parametrize("overexposure", [1.0, 8.0], ids=["1x", "8x"])
def test_a_green_laser_is_not_taken_for_another_colours_core(overexposure):
    """A green laser past full scale: green's clipped band is the widest, so asked green it is
    returned; asked red (whose core clips inside green's at 8 x) or blue, green is named."""
    on, off, _ = stripe_frames(np.random.default_rng(1), overexposure=overexposure, response=GREEN_LASER)
    for dark in (None, off):
        assert len(detect_stripe(on, color="green", dark=dark)) > 0
        for asked in ("red", "blue"):
            with pytest.raises(InputError, match=_named(asked, "green")):
                detect_stripe(on, color=asked, dark=dark)


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
def test_green_asked_of_red_spots_names_red(dark):
    """The grid of red spots 8 x past full scale: green clips in every spot's core."""
    on, off, _ = spot_frames(np.random.default_rng(0), overexposure=8.0)
    with pytest.raises(InputError, match=_named("green", "red")):
        detect_spots(on, color="green", dark=off if dark else None)
    assert len(detect_spots(on, color="red", dark=off if dark else None)) > 0


# --- the real Ciclop frames -------------------------------------------------------------------

CICLOP = real_data("ciclop-laser-stripes")
#: The Ciclop's red-laser frames and their laser-off frames.
CICLOP_FRAMES = {"bust": ("laser_on_object/laser.png", "laser_on_object/laser_background.png"),
                 "board": ("laser_on_pattern/laser-0-255-255-8.png", "laser_on_pattern/laser-background-0-255-255-8.png"),
                 "board x": ("laser_on_pattern/laser-0-255-255-8-x.png",
                             "laser_on_pattern/laser-background-0-255-255-8-x.png")}


def _bgr(frame: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(frame[:, :, ::-1])


@pytest.fixture(scope="module")
def ciclop():
    return {name: tuple(read_image(CICLOP / path) for path in paths) for name, paths in CICLOP_FRAMES.items()}


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize(("stored", "asked"), [("RGB", "green"), ("RGB", "blue"), ("BGR", "red"), ("BGR", "green")])
@pytest.mark.parametrize("name", list(CICLOP_FRAMES))
def test_every_wrong_colour_of_the_ciclop_frames_is_named(ciclop, name, stored, asked, dark):
    """The 24 wrong-colour cases of the real frames (bust and board, RGB and BGR, with and without
    the laser-off frame) still raise."""
    on, off = ciclop[name] if stored == "RGB" else (_bgr(f) for f in ciclop[name])
    with pytest.raises(InputError, match=_named(asked, "red" if stored == "RGB" else "blue")):
        detect_stripe(on, color=asked, dark=off if dark else None)


@pytest.mark.parametrize("dark", [False, True], ids=["no dark", "dark"])
@pytest.mark.parametrize("name", list(CICLOP_FRAMES))
def test_crops_of_the_ciclop_frames_with_the_right_colour_are_returned(ciclop, name, dark):
    """Every 120-row band of the real frames, red asked (most with too few bright lines to be
    trusted at once, so checked further): none raises."""
    on, off = ciclop[name]
    for top in range(0, on.shape[0] - 119, 120):
        band = slice(top, top + 120)
        detect_stripe(np.ascontiguousarray(on[band]), color="red",
                      dark=np.ascontiguousarray(off[band]) if dark else None)

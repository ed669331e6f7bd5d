"""A laser-off frame from the scan's own frames (``scanrig detect --dark median``)."""

import numpy as np
import pytest

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError
from scanrig.io.session import write_image
from scanrig.laser.median_dark import MAX_FRAMES, MIN_FRAMES, median_dark
from scanrig.laser.session_detect import DetectOptions, detect_session
from scanrig.laser.traces import read_traces
from tests.laser.colour_synth import stripe_sweep

SHAPE = (240, 320)
N_FRAMES = 9


@pytest.fixture(scope="module")
def sweep():
    return stripe_sweep(np.random.default_rng(71), N_FRAMES, SHAPE, n_dots=12)


def _session(root, frames, dark=None):
    folder = root / "scan" / "cam0"
    folder.mkdir(parents=True)
    for k, frame in enumerate(frames):
        write_image(folder / f"f{k:02d}.png", frame)
    if dark is not None:
        write_image(folder / "dark.png", dark)
    (root / "session.toml").write_text('laser_mode = "stripe"\nlaser_color = "red"\n')
    return root


def test_median_of_a_swept_spot_is_the_background_exactly(tmp_path):
    rng = np.random.default_rng(3)
    background = rng.integers(0, 200, (30, 40), dtype=np.uint8)
    paths = []
    for k in range(7):   # a bright square that lights each pixel in one frame at most
        frame = background.copy()
        frame[5:10, 5 * k:5 * k + 5] = 255
        paths.append(tmp_path / f"f{k}.png")
        write_image(paths[-1], frame)
    np.testing.assert_array_equal(median_dark(paths, "cam0"), background)


def test_median_session_finds_the_stripe_as_a_laser_off_frame_does(sweep, tmp_path):
    frames, off, centres = sweep
    runs = {}
    for name, dark, source in (("none", None, "file"), ("off", off, "file"), ("median", None, "median")):
        root = _session(tmp_path / name, frames, dark)
        table = detect_session(root, DetectOptions("stripe", "red", dark=source))
        u, v, line, rank, frame = (table[c].to_numpy() for c in ("u", "v", "line", "rank", "frame"))
        within = []
        for k, centre_u in enumerate(centres):
            best = (frame == f"f{k:02d}") & (rank == 0) & (v == line)
            within.append(np.abs(u[best] - centre_u[line[best]]) < 0.5)
        runs[name] = (np.concatenate(within).sum(), len(table))
    assert runs["median"][0] >= runs["off"][0] - 0.01 * N_FRAMES * SHAPE[0]
    assert runs["median"][0] > runs["none"][0]
    assert runs["median"][1] < runs["none"][1]      # fewer texture candidates


def test_median_option_equals_writing_that_median_as_the_dark_frame(sweep, tmp_path):
    frames, _, _ = sweep
    by_option = detect_session(_session(tmp_path / "a", frames), DetectOptions("stripe", "red", dark="median"))
    paths = sorted((tmp_path / "a" / "scan" / "cam0").glob("f*.png"))
    written = _session(tmp_path / "b", frames, median_dark(paths, "cam0"))
    assert by_option.equals(detect_session(written, DetectOptions("stripe", "red")))
    _, meta = read_traces(tmp_path / "a" / "traces.parquet")
    assert meta["options"]["dark"] == "median"


def test_at_most_max_frames_are_read_evenly(tmp_path):
    background = np.full((8, 8), 40, np.uint8)
    paths = []
    for k in range(MAX_FRAMES + 20):
        path = tmp_path / f"f{k}.png"
        write_image(path, background)
        paths.append(path)
    paths[1].write_bytes(b"not an image")   # between two of the evenly spread frames read
    np.testing.assert_array_equal(median_dark(paths, "cam0"), background)


def test_bad_input_is_named(sweep, tmp_path, capsys):
    frames, _, _ = sweep
    few = _session(tmp_path / "few", frames[:MIN_FRAMES - 1])
    with pytest.raises(InputError, match=f"camera 'cam0': a median laser-off frame needs at least {MIN_FRAMES} "
                                         f"scan frames, found {MIN_FRAMES - 1}"):
        detect_session(few, DetectOptions("stripe", "red", dark="median"))
    odd = _session(tmp_path / "odd", frames[:MIN_FRAMES])
    write_image(odd / "scan" / "cam0" / "f04.png", frames[0][:100])
    with pytest.raises(FileFormatError, match=r"f04.png: frame is 320x100 8-bit colour but f00.png of camera "
                                              r"'cam0' is 320x240 8-bit colour"):
        detect_session(odd, DetectOptions("stripe", "red", dark="median"))
    turntable = _session(tmp_path / "turntable", frames[:MIN_FRAMES])
    (turntable / "scan" / "object_poses.csv").write_text("frame,qw,qx,qy,qz,tx,ty,tz\n")
    assert main(["detect", str(turntable), "--dark", "median"]) == 2
    assert ("object_poses.csv: the object moves between frames, so the median of its frames is not a laser-off "
            "frame; take one at every step (scan/<camera>/dark/<frame>.<ext>) instead") in capsys.readouterr().err
    assert main(["detect", str(turntable), "--dark", "mean"]) == 2
    assert "dark must be one of ('file', 'median'), got 'mean'" in capsys.readouterr().err
    assert not (turntable / "traces.parquet").exists()

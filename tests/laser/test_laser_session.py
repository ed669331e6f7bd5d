"""Whole-session detection, traces.parquet, resume, overlays and the ``scanrig detect`` verb."""

import re

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from scanrig.cli.main import main
from scanrig.errors import FileFormatError, InputError
from scanrig.io.session import Session, read_image, write_image
from scanrig.laser.session_detect import (DetectOptions, colour_mismatches, detect_frame, detect_session,
                                          options_from_session)
from scanrig.laser.traces import SCHEMA, read_traces, write_traces

from .synth import spot_image, stripe_image

N_FRAMES = 5
CAMERAS = ("cam2", "cam10")  # natural order: cam2 before cam10


def _true_spot(cam, k):
    return 40.3 + 11.1 * k + 3.7 * (cam == "cam10"), 30.6 + 7.9 * k


@pytest.fixture
def session(tmp_path):
    rng = np.random.default_rng(501)
    for cam in CAMERAS:
        folder = tmp_path / "scan" / cam
        folder.mkdir(parents=True)
        for k in range(N_FRAMES):
            u, v = _true_spot(cam, k)
            spots = [(u, v, 180.0, 1.5, 1.5)] + ([(u + 20, v + 10, 90.0, 1.5, 1.5)] if k == 2 else [])
            img = spot_image((120, 160), spots, rng, 40.0, 2.0)
            write_image(folder / f"f{k}.png", np.stack([img, np.full_like(img, 40), np.full_like(img, 40)], -1))
    (tmp_path / "session.toml").write_text('laser_mode = "spot"\nlaser_color = "red"\n')
    return tmp_path


@pytest.mark.parametrize("workers", [1, 2])
def test_session_detection_finds_every_spot_in_order(session, workers):
    table = detect_session(session, workers=workers)
    on_disk, meta = read_traces(session / "traces.parquet")
    assert on_disk.equals(table) and table.schema.equals(SCHEMA)
    assert meta["options"]["color"] == "red" and len(meta["frames_done"]) == 2 * N_FRAMES
    assert table.column("camera").to_pylist()[0] == "cam2"
    assert len(table) == 2 * N_FRAMES + 2  # one reflection in frame f2 of each camera
    rank0 = table.filter(pa.compute.equal(table["rank"], 0))
    for cam, frame, u, v in zip(*(rank0[c].to_pylist() for c in ("camera", "frame", "u", "v"))):
        tu, tv = _true_spot(cam, int(frame[1:]))
        assert abs(u - tu) < 0.1 and abs(v - tv) < 0.1


def test_resume_skips_done_frames_and_refuses_other_options(session):
    first = detect_session(session)
    meta_only = first.filter(pa.compute.not_equal(first["frame"], "f4"))
    done = [[c, f"f{k}"] for c in CAMERAS for k in range(N_FRAMES - 1)]
    write_traces(session / "traces.parquet", meta_only, {"options": DetectOptions("spot", "red").as_dict(),
                                                         "frames_done": done})
    for cam in CAMERAS:  # a resumed run must not read the finished frames again
        (session / "scan" / cam / "f1.png").write_bytes(b"not an image")
    resumed = detect_session(session, resume=True)
    assert resumed.equals(first)
    with pytest.raises(FileFormatError, match="traces.parquet: was made with options .* run without --resume"):
        detect_session(session, DetectOptions("stripe", "red"), resume=True)


def _stripe_centre(rows):
    return 60.3 + 0.05 * rows


@pytest.fixture
def stripe_session(tmp_path):
    """Grey frames of a steep stripe crossing a horizontal one (an edge the laser is not on)."""
    rng = np.random.default_rng(502)
    folder = tmp_path / "scan" / "cam0"
    folder.mkdir(parents=True)
    for k in range(2):
        steep = stripe_image((120, 160), _stripe_centre, rng, noise=2.0)
        flat = stripe_image((120, 160), lambda cols: np.full_like(cols, 90.4), rng, background=0.0, noise=0.0,
                            along="columns")
        write_image(folder / f"f{k}.png", np.maximum(steep, flat))
    (tmp_path / "session.toml").write_text('laser_mode = "stripe"\n')
    return tmp_path


def test_stripes_scanned_along_rows_only_when_asked(stripe_session, capsys):
    auto = detect_session(stripe_session)
    along_columns = auto["u"].to_numpy() == auto["line"].to_numpy()
    assert along_columns.any()           # the flat stripe is scanned along columns by default
    assert main(["detect", str(stripe_session), "--direction", "rows"]) == 0
    rows, meta = read_traces(stripe_session / "traces.parquet")
    assert meta["options"]["direction"] == "rows"
    v, line, rank, u = (rows[c].to_numpy() for c in ("v", "line", "rank", "u"))
    assert np.array_equal(v, line)
    steep = (rank == 0) & (np.abs(line - 90) > 6)     # rows off the flat stripe
    assert steep.sum() == 2 * (120 - 13)
    np.testing.assert_allclose(u[steep], _stripe_centre(line[steep]), atol=0.1)
    assert main(["detect", str(stripe_session), "--direction", "diagonal"]) == 2
    assert "direction must be one of ('auto', 'rows', 'columns'), got 'diagonal'" in capsys.readouterr().err
    assert main(["detect", str(stripe_session), "--mode", "spot", "--direction", "rows"]) == 2
    assert "direction 'rows' applies to stripes; spot mode takes no direction" in capsys.readouterr().err


def test_resume_of_a_file_from_before_the_later_options_takes_their_defaults(session):
    first = detect_session(session)
    options = DetectOptions("spot", "red").as_dict()
    del options["direction"], options["dark"]
    write_traces(session / "traces.parquet", first, {"options": options,
                                                     "frames_done": [[c, f"f{k}"] for c in CAMERAS for k in range(N_FRAMES)]})
    assert detect_session(session, resume=True).equals(first)


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 1), (np.uint16, 16)], ids=["8-bit", "16-bit"])
def test_resume_of_a_file_clipped_at_full_scale_is_refused(tmp_path, dtype, scale):
    """A file from before ``saturation_level`` clipped every frame at its dtype's maximum; the frames
    left are now clipped at the level found from them: one file would mix both."""
    _clipped_stripe_session(tmp_path, dtype, scale)
    write_image(tmp_path / "scan" / "cam0" / "f1.png", read_image(tmp_path / "scan" / "cam0" / "f0.png"))
    options = DetectOptions("stripe").as_dict()
    del options["saturation_level"]
    first = detect_session(tmp_path)
    write_traces(tmp_path / "traces.parquet", first.filter(pa.compute.equal(first["frame"], "f0")),
                 {"options": options, "frames_done": [["cam0", "f0"]]})
    with pytest.raises(FileFormatError, match=r"traces.parquet: was made with options .*'saturation_level': None}, "
                                              r"not .*'saturation_level': 'auto'}; run without --resume"):
        detect_session(tmp_path, resume=True)


def test_unreadable_and_mismatched_frames_are_named(session):
    (session / "scan" / "cam2" / "f3.png").write_bytes(b"garbage")
    with pytest.raises(FileFormatError, match=r"f3.png: cannot decode image"):
        detect_session(session)
    write_image(session / "scan" / "cam2" / "f3.png", np.zeros((100, 160, 3), np.uint8))
    message = r"f3.png: frame is 160x100 8-bit colour but f0.png of camera 'cam2' is 160x120"
    with pytest.raises(FileFormatError, match=message):
        detect_session(session, workers=2)
    write_image(session / "scan" / "cam2" / "f3.png", np.zeros((120, 160, 3), np.uint16))
    with pytest.raises(FileFormatError, match=r"f3.png: frame is 160x120 16-bit colour but .* 8-bit colour"):
        detect_session(session)
    (session / "scan" / "cam2" / "f3.png").write_bytes(b"")
    with pytest.raises(FileFormatError, match=r"f3.png: image file is empty"):
        detect_session(session)
    (session / "scan" / "cam2" / "f3.png").unlink()
    cv2.imwrite(str(session / "scan" / "cam2" / "f3.tif"), np.zeros((120, 160), np.float32))
    with pytest.raises(FileFormatError, match=r"f3.tif: expected an 8- or 16-bit image, got float32"):
        detect_session(session)


def test_dark_frame_is_used(session):
    cam = session / "scan" / "cam2"
    glare = np.zeros((120, 160, 3), np.uint8)
    glare[80:83, 120:123, 0] = 150  # a fixed red glint, present with the laser off too
    write_image(cam / "dark.png", glare)
    for k in range(N_FRAMES):
        img = read_image(cam / f"f{k}.png")
        write_image(cam / f"f{k}.png", np.clip(img.astype(int) + glare, 0, 255).astype(np.uint8))
    table = detect_session(session)
    assert len(table.filter(pa.compute.equal(table["camera"], "cam2"))) == N_FRAMES + 1


def test_each_frame_takes_its_own_laser_off_frame(tmp_path):
    """A moving object (a turntable): every frame has its own laser-off frame in
    ``scan/<camera>/dark/``, with the frame's stem; a frame without one takes the camera's
    ``dark.png``. Each frame's candidates are those of the frame with its laser-off frame."""
    from tests.laser.colour_synth import stripe_frames

    folder = tmp_path / "scan" / "cam0"
    (folder / "dark").mkdir(parents=True)
    pairs = [stripe_frames(np.random.default_rng(seed))[:2] for seed in range(3)]  # other print each time
    for k, (on, off) in enumerate(pairs):
        write_image(folder / f"f{k}.png", on)
        if k < 2:
            write_image(folder / "dark" / f"f{k}.png", off)
    write_image(folder / "dark.png", pairs[2][1])
    (tmp_path / "session.toml").write_text('laser_mode = "stripe"\nlaser_color = "red"\n')
    options = options_from_session(Session(tmp_path))
    table = detect_session(tmp_path, options, workers=2)
    for k, (on, off) in enumerate(pairs):
        mine = np.sort(table.filter(pa.compute.equal(table["frame"], f"f{k}"))["u"].to_numpy())
        assert mine.size > 400
        np.testing.assert_array_equal(mine, np.sort(detect_frame(on, off, options)["u"].to_numpy()))
        assert not np.array_equal(mine, np.sort(detect_frame(on, None, options)["u"].to_numpy()))
    write_image(folder / "dark" / "f1.png", pairs[1][1][:100])
    with pytest.raises(FileFormatError, match=r"dark/f1.png: laser-off frame is 640x100 8-bit colour but dark.png of "
                                              r"camera 'cam0' is 640x480 8-bit colour"):
        detect_session(tmp_path, options)


def test_no_candidate_anywhere_writes_nothing_and_keeps_an_earlier_file(session):
    """Green asked of red spots: no candidate in any frame, so ``detect_session`` returns an empty
    table and leaves the traces file of an earlier run as it was (the CLI then exits 2)."""
    first = detect_session(session)
    before = (session / "traces.parquet").read_bytes()
    options = DetectOptions("spot", "green")
    assert len(detect_session(session, options)) == 0
    assert (session / "traces.parquet").read_bytes() == before and len(first) > 0
    (session / "traces.parquet").unlink()
    assert len(detect_session(session, options, checkpoint_s=0.0)) == 0
    assert not (session / "traces.parquet").exists()


def test_traces_file_validation(tmp_path):
    path = tmp_path / "traces.parquet"
    with pytest.raises(FileFormatError, match="traces.parquet: traces file not found"):
        read_traces(path)
    path.write_bytes(b"PAR1 nonsense")
    with pytest.raises(FileFormatError, match="traces.parquet: not a readable Parquet file"):
        read_traces(path)
    pq.write_table(SCHEMA.empty_table().drop_columns(["sigma_px"]), path)
    with pytest.raises(FileFormatError, match="traces.parquet: missing column 'sigma_px'"):
        read_traces(path)
    bad = pa.table({**{f.name: pa.array([], f.type) for f in SCHEMA}, "rank": pa.array([], pa.float64())})
    pq.write_table(bad, path)
    with pytest.raises(FileFormatError, match="column 'rank' must be int32, got double"):
        read_traces(path)


@pytest.mark.parametrize("raw, reason", [(b'{"format_version": 1', "is not valid JSON"),
                                         (b'{"frames_done": "\xfe"}', "is not valid JSON"),  # not UTF-8
                                         (b"[1, 2]", "must be a JSON object, got list")])
def test_traces_metadata_that_is_not_a_json_object_is_named(tmp_path, raw, reason):
    """A damaged metadata entry is a FileFormatError naming the file (bytes that are not UTF-8
    raised UnicodeDecodeError before)."""
    path = tmp_path / "traces.parquet"
    pq.write_table(SCHEMA.empty_table().replace_schema_metadata({b"scanrig": raw}), path)
    with pytest.raises(FileFormatError, match=f"traces.parquet: scanrig metadata {reason}"):
        read_traces(path)


def test_cli_detect_writes_traces_and_overlay(session, capsys):
    assert main(["detect", str(session), "--workers", "2", "--overlay", "f2"]) == 0
    out = capsys.readouterr().out
    assert "12 candidates in 10 camera frames (10 with candidates)" in out
    overlay = read_image(session / "overlays" / "f2_cam10.png")
    assert overlay.shape == (120, 160, 3)
    u, v = _true_spot("cam10", 2)
    assert tuple(overlay[int(round(v)), int(round(u))]) == (0, 255, 0)  # the green centre cross


def test_cli_bad_input_exits_2_naming_the_problem(session, capsys):
    assert main(["detect", str(session / "missing")]) == 2
    assert "missing: session folder not found" in capsys.readouterr().err
    assert main(["detect", str(session), "--mode", "blob"]) == 2
    assert "mode must be one of ('spot', 'stripe'), got 'blob'" in capsys.readouterr().err
    assert main(["detect", str(session), "--roi", "1,2,3"]) == 2
    assert "--roi must be four integers u0,v0,u1,v1, got '1,2,3'" in capsys.readouterr().err


def test_saturation_level_option_is_checked_and_recorded(session, capsys):
    assert main(["detect", str(session), "--saturation-level", "bright"]) == 2
    assert "error: --saturation-level must be a number of DN or 'auto', got 'bright'" in capsys.readouterr().err
    assert main(["detect", str(session), "--saturation-level", "-5"]) == 2
    assert "error: saturation_level must be a positive number of DN or 'auto', got -5.0" in capsys.readouterr().err
    assert main(["detect", str(session), "--saturation-level", "300"]) == 2
    assert (f"error: {session / 'scan' / 'cam2' / 'f0.png'}: saturation_level must be in (0, 255] for uint8 images, "
            "got 300.0") in capsys.readouterr().err
    with pytest.raises(InputError, match="saturation_level must be a positive number of DN or 'auto', got 'max'"):
        DetectOptions(saturation_level="max")
    assert main(["detect", str(session), "--saturation-level", "auto"]) == 0
    assert read_traces(session / "traces.parquet")[1]["options"]["saturation_level"] == "auto"


def test_saturation_level_from_session_toml(session, capsys):
    """``saturation_level`` in session.toml is the default of ``--saturation-level``; a bad value
    names the file."""
    toml = session / "session.toml"
    toml.write_text('laser_mode = "spot"\nlaser_color = "red"\nsaturation_level = 250\n')
    assert options_from_session(Session(session)).saturation_level == 250
    assert options_from_session(Session(session), saturation_level="auto").saturation_level == "auto"
    assert main(["detect", str(session)]) == 0
    assert read_traces(session / "traces.parquet")[1]["options"]["saturation_level"] == 250
    toml.write_text('laser_mode = "spot"\nlaser_color = "red"\nsaturation_level = "max"\n')
    assert main(["detect", str(session)]) == 2
    assert (f"error: {toml}: saturation_level must be a positive number of DN or \"auto\", got 'max'"
            in capsys.readouterr().err)


def _clipped_stripe_session(root, dtype, scale):
    """Grey frames of a stripe clipped at 255 DN (a flat top 5-6 px wide), values times ``scale``
    (rounded)."""
    rng = np.random.default_rng(503)
    folder = root / "scan" / "cam0"
    folder.mkdir(parents=True)
    frame = np.round(stripe_image((60, 80), _stripe_centre, rng, amplitude=900.0, sigma=2.0, noise=2.0) * float(scale))
    write_image(folder / "f0.png", frame.astype(dtype))
    (root / "session.toml").write_text('laser_mode = "stripe"\n')
    return frame.astype(dtype)


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 235 / 255), (np.uint16, 16)],
                         ids=["8-bit clipped at 235", "16-bit: 12-bit data"])
def test_the_default_clip_level_is_found_from_the_data(tmp_path, dtype, scale):
    """A camera whose data clip below the dtype's maximum (a colour channel's white balance gain
    below 1; 12-bit data in a 16-bit file, clipped at 4080): only the found level knows the clipped
    top, which the session's default leaves out of the fit, unlike the detector's own default."""
    from scanrig import detect_stripe

    frame = _clipped_stripe_session(tmp_path, dtype, scale)
    table = detect_session(tmp_path)
    assert table.drop_columns(["camera", "frame"]).equals(detect_stripe(frame, saturation_level="auto")
                                                         .drop_columns(["camera", "frame"]))
    assert table["saturated"].to_numpy().any()
    assert not detect_stripe(frame)["saturated"].to_numpy().any()


@pytest.mark.parametrize("red_gain, asked, shown", [(0.85, "red", None), (1.0, "green", "red"), (1.0, "blue", "red")])
def test_an_over_exposed_red_stripe_on_print_is_told_from_the_texture(tmp_path, red_gain, asked, shown):
    """The rendered red stripe 8 times past full scale on printed paper, without a laser-off frame:
    its colour difference is small in the white core, so the rank-0 peaks summed over the rows
    give green two to three times red's, from the print's texture (red clipped at 217 DN by white
    balance: a third), which told a red session to use green, and green or blue ones nothing or
    green. The detectors' own check, on bright and clipped candidates, names red where the laser
    is red, and nothing where it was asked for."""
    from dataclasses import replace

    from .colour_synth import RESPONSE, stripe_frames

    on = stripe_frames(np.random.default_rng(0), response=replace(RESPONSE, white_balance=(red_gain, 1.0, 1.0)))[0]
    folder = tmp_path / "scan" / "cam0"
    folder.mkdir(parents=True)
    write_image(folder / "f0.png", on)
    options = DetectOptions("stripe", asked)
    lines = colour_mismatches(tmp_path, options, detect_session(tmp_path, options))
    assert lines == ([] if shown is None else [f"cam0: no {asked} laser in {folder / 'f0.png'}; the frames show a "
                                               f"{shown} one: use --color {shown} (or laser_color = '{shown}' in "
                                               "session.toml)"])


def test_a_red_stripe_detected_as_grey_is_named_by_the_colours_among_themselves(tmp_path):
    """The rendered red stripe at half full scale on printed paper, with its laser-off frame, in a
    session without a laser colour: grey (the frames' luma) finds less than three times less light
    than red, so the line comes from the colours among themselves, red far above green and blue."""
    from .colour_synth import stripe_frames

    on, off, _ = stripe_frames(np.random.default_rng(0), overexposure=0.5)
    folder = tmp_path / "scan" / "cam0"
    folder.mkdir(parents=True)
    write_image(folder / "f0.png", on)
    write_image(folder / "dark.png", off)
    options = DetectOptions("stripe", "grey")
    [line] = colour_mismatches(tmp_path, options, detect_session(tmp_path, options))
    assert re.fullmatch(rf"cam0: the laser in {re.escape(str(folder / 'f0.png'))} is red \(\d+ times the light of the "
                        r"other colours\), detected as grey on the frames' luma: use --color red \(or laser_color = "
                        r"'red' in session.toml\)", line), line


@pytest.mark.parametrize("frames, laser", [(lambda f: f, "red"), (lambda f: np.ascontiguousarray(f[:, :, ::-1]), "blue")],
                         ids=["RGB", "BGR"])
def test_spots_of_another_colour_are_named(tmp_path, frames, laser):
    """A rendered grid of over-exposed red spots with its laser-off frame, saved as RGB or with red
    and blue swapped, detected as red: the swapped frames' camera is named with its blue laser
    (red finds no spot of half the clip level, as the detectors' own check counts laser light),
    the right colour's is not."""
    from .colour_synth import spot_frames

    on, off = spot_frames(np.random.default_rng(7))[:2]
    folder = tmp_path / "scan" / "cam0"
    folder.mkdir(parents=True)
    write_image(folder / "f0.png", frames(on))
    write_image(folder / "dark.png", frames(off))
    options = DetectOptions("spot", "red")
    lines = colour_mismatches(tmp_path, options, detect_session(tmp_path, options))
    if laser == "red":
        assert lines == []
    else:
        assert len(lines) == 1
        assert lines == [f"cam0: no red laser in {folder / 'f0.png'}; the frames show a blue one: use --color blue "
                         "(or laser_color = 'blue' in session.toml)"]

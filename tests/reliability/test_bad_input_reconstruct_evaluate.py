"""Bad-input matrix, part: `scanrig reconstruct` and `scanrig evaluate` (rig.toml, traces.parquet, PLY)."""

import pytest

from tests.reliability.cases import edit_text, no_change, remove, truncate, write_bytes, write_text
from tests.reliability.matrix import assert_fails_cleanly

RECONSTRUCT = ["reconstruct", "{s}"]
EVALUATE = ["evaluate", "{s}/points.ply", "--truth", "{s}/truth"]

#: case -> (setup on the good session, argv with {s} for the session, expected error line)
CASES = {
    "rig.toml missing": (remove("rig.toml"), RECONSTRUCT,
                         r"rig.toml: rig file not found \(run `scanrig calibrate` first or pass --rig\)"),
    "--rig file missing": (no_change, RECONSTRUCT + ["--rig", "{s}/nope.toml"], r"nope.toml: rig file not found"),
    "traces.parquet missing": (remove("traces.parquet"), RECONSTRUCT,
                               r"traces.parquet: traces file not found \(run `scanrig detect` first\)"),
    "traces.parquet not Parquet": (write_bytes("traces.parquet", b"PAR1 junk"), RECONSTRUCT,
                                   r"traces.parquet: not a readable Parquet file: .*magic bytes not found"),
    "traces.parquet truncated": (truncate("traces.parquet", 200), RECONSTRUCT,
                                 r"traces.parquet: not a readable Parquet file"),
    "rig.toml unknown top-level key": (write_text("rig.toml", "x = 1\n"), RECONSTRUCT,
                                       r"rig.toml: top level: unknown field 'x'; allowed: \['cameras', "),
    "rig.toml misspelt key": (edit_text("rig.toml", "units =", "unts ="), RECONSTRUCT,
                              r"rig.toml: top level: unknown field 'unts' \(did you mean 'units'\?\)"),
    "rig.toml duplicate camera names": (edit_text("rig.toml", 'name = "cam1"', 'name = "cam0"'), RECONSTRUCT,
                                        r"rig.toml: camera names must be unique in a rig, duplicated: \['cam0'\]"),
    "rig.toml NaN focal length": (edit_text("rig.toml", "60.0", "nan"), RECONSTRUCT,
                                  r"rig.toml: \[\[cameras\]\] #1 \('cam0'\): camera 'cam0' params \(pinhole\) "
                                  r"must be finite, got \[nan, 60.0, 31.5, 23.5\]"),
    "rig.toml inf translation": (edit_text("rig.toml", "    -0.1,", "    inf,"), RECONSTRUCT,
                                 r"rig.toml: \[\[cameras\]\] #1 \('cam0'\): .*finite"),
    "rig.toml unknown camera model": (edit_text("rig.toml", '"pinhole"', '"pinhol"'), RECONSTRUCT,
                                      r"rig.toml: \[\[cameras\]\] #1 \('cam0'\): .*'pinhol'"),
    "rig.toml wrong units": (edit_text("rig.toml", 'units = "m"', 'units = "mm"'), RECONSTRUCT,
                             r"rig.toml: .*units.*'mm'"),
    "rig.toml missing width": (edit_text("rig.toml", "width = 64\n", ""), RECONSTRUCT,
                               r"rig.toml: \[\[cameras\]\] #1.*missing field 'width'"),
    "rig.toml image size differs from frames": (edit_text("rig.toml", "width = 64", "width = 640"), RECONSTRUCT,
                                                r"rig.toml: camera 'cam0' is 640x48 but scan/cam0/f0.png is 64x48"),
    "rig.toml lacks a scan camera": (lambda s: (s / "scan" / "cam1").rename(s / "scan" / "camX"), RECONSTRUCT,
                                     r"rig.toml: has no camera \['camX'\] for the scan folders \['cam0', 'camX'\]"),
    "rig.toml not TOML": (write_text("rig.toml", "[[cameras]\n"), RECONSTRUCT, r"rig.toml: not valid TOML"),
    "--light-plane with spot traces": (no_change, RECONSTRUCT + ["--light-plane", "{s}/plane.toml"],
                                       r"traces.parquet: holds spot traces; --light-plane needs stripe traces"),
    "points.ply missing": (remove("points.ply"), EVALUATE, r"points.ply: no such file"),
    "points.ply not PLY": (write_bytes("points.ply", b"garbage"), EVALUATE,
                           r"points.ply: not a readable PLY file \(line 1: expected 'ply'\)"),
    "points.ply truncated": (truncate("points.ply", 300), EVALUATE,
                             r"points.ply: not a readable PLY file \(line \d+: early end-of-file\)"),
    "points.ply without vertices": (write_bytes("points.ply", b"ply\nformat ascii 1.0\nend_header\n"), EVALUATE,
                                    r"points.ply: has no 'vertex' element \(elements: \[\]\)"),
    "truth folder without meshes": (no_change, ["evaluate", "{s}/points.ply", "--truth", "{s}/nope"],
                                    r"nope/meshes: no true meshes \(\*.ply\) found; --truth must be a simulator truth/"),
    "truth mesh unreadable": (write_bytes("truth/meshes/box.ply", b"junk"), EVALUATE,
                              r"truth/meshes/box.ply: cannot read mesh"),
    "--rig file missing (evaluate)": (no_change, EVALUATE + ["--rig", "{s}/nope.toml"], r"nope.toml: file not found"),
    "--rig is not TOML": (no_change, EVALUATE + ["--rig", "{s}/points.ply"], r"points.ply: not valid TOML"),
    "--rig without truth/rig.toml": (remove("truth/rig.toml"), EVALUATE + ["--rig", "{s}/rig.toml"],
                                     r"truth/rig.toml: file not found"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_reconstruct_evaluate_bad_input(good_session, capsys, case):
    setup, argv, message = CASES[case]
    setup(good_session)
    capsys.readouterr()
    argv = [a.format(s=good_session) for a in argv]
    assert_fails_cleanly(argv, message, good_session, capsys)

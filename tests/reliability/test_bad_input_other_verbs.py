"""Bad-input matrix, part: `calibrate`, `relocate`, `target`, `filter`, `export`, `report`, `demo`."""

import shutil

import pytest

from tests.reliability.cases import no_change, remove, write_bytes, write_text
from tests.reliability.matrix import assert_fails_cleanly


def with_target(then=no_change):
    """A chessboard target.toml and calibration/ images (the scan frames: no target in them)."""
    def setup(s):
        from scanrig.targets import chessboard, save_target

        save_target(chessboard(inner_corners=(9, 6), square_m=0.03), s / "target.toml")
        shutil.copytree(s / "scan", s / "calibration")
        then(s)
    return setup


KNOWN = ["relocate", "{s}", "--camera", "cam0", "--points", "{s}/known.csv"]
CORNERS = ["calibrate", "{s}", "--corners", "{s}/corners.csv"]
CORNERS_HEADER = "image,camera,point_id,x,y,weight\n"

#: case -> (setup on the good session, argv with {s} for the session, expected error line)
CASES = {
    "calibrate without target.toml": (no_change, ["calibrate", "{s}"], r"target.toml: file not found"),
    "calibrate misspelt target kind": (write_text("target.toml", "kind = 'chessbord'\n"), ["calibrate", "{s}"],
                                       r"target.toml: target: kind must be one of \[.*'chessboard'.*\], got 'chessbord'"),
    "calibrate without calibration images": (lambda s: with_target()(s) or shutil.rmtree(s / "calibration"),
                                             ["calibrate", "{s}"], r"calibration: calibration folder not found in session"),
    "calibrate target never seen": (with_target(), ["calibrate", "{s}"],
                                    r"camera 'cam0': the target was never found in its calibration images"),
    "calibrate unknown model": (with_target(), ["calibrate", "{s}", "--model", "opencv99"],
                                r"model must be one of \['opencv4', 'opencv5', 'opencv8'\], got 'opencv99'"),
    "corners CSV missing": (with_target(), CORNERS, r"corners.csv: corners file not found"),
    "corners CSV missing column": (with_target(write_text("corners.csv", "image,camera,point_id,x\n")), CORNERS,
                                   r"corners.csv: missing column\(s\) \['y'\]; expected header "
                                   r"image,camera,point_id,x,y,weight"),
    "corners CSV short row": (with_target(write_text("corners.csv", CORNERS_HEADER + "s0,cam0,1,10.5\n")), CORNERS,
                              r"corners.csv: line 2: the cells do not match the header's 6 columns"),
    "corners CSV NaN pixel": (with_target(write_text("corners.csv", CORNERS_HEADER + "s0,cam0,1,nan,20.25,1\n")),
                              CORNERS, r"corners.csv: line 2: x, y must be finite pixel coordinates, got nan, 20.25"),
    "relocate unknown camera": (no_change, ["relocate", "{s}", "--camera", "cam9", "--points", "{s}/known.csv"],
                                r"--camera 'cam9' is not in .*rig.toml; cameras are \['cam0', 'cam1'\]"),
    "known points missing": (no_change, KNOWN, r"known.csv: known points file not found"),
    "known points missing column": (write_text("known.csv", "point,x,y,z,u\n1,0,0,0,1\n"), KNOWN,
                                    r"known.csv: missing column\(s\) \['v'\]; expected header point,x,y,z,u,v"),
    "known points too few": (write_text("known.csv", "point,x,y,z,u,v\n1,0,0,0,1,2\n"), KNOWN,
                             r"known.csv: 1 known points; at least 5 are needed"),
    "known points short row": (write_text("known.csv", "point,x,y,z,u,v\np1,0,0,0,1\n"), KNOWN,
                               r"known.csv: line 2: the cells do not match the header's 6 columns"),
    "target file missing": (no_change, ["target", "print", "{s}/nope.toml", "--out", "{s}/prints"],
                            r"nope.toml: file not found"),
    "target field missing": (write_text("t.toml", "kind = 'chessboard'\nsquare_m = 0.03\n"),
                             ["target", "print", "{s}/t.toml", "--out", "{s}/prints"],
                             r"t.toml: target \(kind = 'chessboard'\): missing field 'inner_corners'"),
    "target kind an array": (write_text("t.toml", "kind = [1, 2]\n"),
                             ["target", "print", "{s}/t.toml", "--out", "{s}/prints"],
                             r"t.toml: target: kind must be one of \[.*'chessboard'.*\], got \[1, 2\]"),
    "target --out a file": (write_text("t.toml", "kind = 'chessboard'\ninner_corners = [9, 6]\nsquare_m = 0.03\n"),
                            ["target", "print", "{s}/t.toml", "--out", "{s}/points.ply"],
                            r"--out \S+points.ply: expected a folder for the print files, but \S+points.ply is a file"),
    "target unknown action": (no_change, ["target", "frobnicate", "{s}/t.toml"], r"action must be 'print', got 'frobnicate'"),
    "filter input missing": (no_change, ["filter", "{s}/nope.ply"], r"nope.ply: no such file"),
    "filter input not PLY": (write_bytes("points.ply", b"garbage"), ["filter", "{s}/points.ply"],
                             r"points.ply: not a readable PLY file \(line 1: expected 'ply'\)"),
    "filter q out of range": (no_change, ["filter", "{s}/points.ply", "--q", "0.9"],
                              r"q \(tolerated fraction of bad data\) must be in \(0, 0.5\], got 0.9"),
    "filter unknown architecture": (no_change, ["filter", "{s}/points.ply", "--architecture", "cnn"],
                                    r"architecture must be one of \('ridge', 'mlp'\), got 'cnn'"),
    "export unknown format": (no_change, ["export", "{s}", "--format", "xyz"],
                              r"format must be one of ply, ply-ascii, stl, obj, .*; got 'xyz'"),
    "export missing session": (no_change, ["export", "{s}/nope", "--format", "ply"], r"nope: session folder not found"),
    "export nothing to export": (remove("points.ply"), ["export", "{s}", "--format", "ply"],
                                 r"has none of points.ply, surface.ply, mesh.ply to export as ply"),
    "report missing session": (no_change, ["report", "{s}/nope"], r"nope: session folder not found"),
    "report unreadable points": (write_bytes("points.ply", b"garbage"), ["report", "{s}"],
                                 r"points.ply: not a readable PLY file \(line 1: expected 'ply'\)"),
    "demo into a scanned session": (no_change, ["demo", "--out", "{s}", "--quick"],
                                    r"is not empty \(it holds .*\) and scanrig demo would overwrite files there"),
    "demo unknown mode": (no_change, ["demo", "--out", "{s}/demo", "--mode", "blob"],
                          r"mode must be one of \('stripe', 'spot'\), got 'blob'"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_other_verbs_bad_input(good_session, capsys, case):
    setup, argv, message = CASES[case]
    setup(good_session)
    capsys.readouterr()
    argv = [a.format(s=good_session) for a in argv]
    assert_fails_cleanly(argv, message, good_session, capsys)

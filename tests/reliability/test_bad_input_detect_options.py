"""Bad-input matrix, part: `scanrig detect` options, dark frames, session.toml lists and --resume."""

import pytest

from tests.reliability.cases import no_change, write_bytes, write_text
from tests.reliability.matrix import assert_fails_cleanly

DETECT = ["detect", "{s}"]

#: case -> (setup on the good session, argv with {s} for the session, expected error line)
CASES = {
    "--roi not four integers": (no_change, DETECT + ["--roi", "1,2,3"],
                                r"--roi must be four integers u0,v0,u1,v1, got '1,2,3'"),
    "--roi reversed": (no_change, DETECT + ["--roi", "5,5,1,1"],
                       r"cam0/f0.png: roi \(u0, v0, u1, v1\) = \(5, 5, 1, 1\) must lie inside the 64x48 frame "
                       r"and be at least 3x3 pixels"),
    "--roi outside the frame": (no_change, DETECT + ["--roi", "0,0,1000,1000"],
                                r"cam0/f0.png: roi .* = \(0, 0, 1000, 1000\) must lie inside the 64x48 frame"),
    "--color unknown": (no_change, DETECT + ["--color", "purple"],
                        r"color must be one of \('grey', 'red', 'green', 'blue'\), got 'purple'"),
    "--direction unknown": (no_change, DETECT + ["--mode", "stripe", "--direction", "diagonal"],
                            r"direction must be one of \('auto', 'rows', 'columns'\), got 'diagonal'"),
    "--direction in spot mode": (no_change, DETECT + ["--direction", "rows"],
                                 r"direction 'rows' applies to stripes; spot mode takes no direction"),
    "--workers 0": (no_change, DETECT + ["--workers", "0"], r"workers must be at least 1, got 0"),
    "--k-detect negative": (no_change, DETECT + ["--k-detect", "-1"],
                            r"k_detect must be a positive number of noise sigma, got -1.0"),
    "--overlay of an unknown frame": (no_change, DETECT + ["--overlay", "nope"], r"no scan frame named 'nope' in "),
    "dark frame unreadable": (write_bytes("scan/cam0/dark.png", b"x"), DETECT,
                              r"cam0/dark.png: cannot decode image \(unreadable or truncated file\)"),
    "session.toml duplicate cameras": (write_text("session.toml", 'cameras = ["cam0", "cam0"]\n'), DETECT,
                                       r"session.toml: cameras must be unique, duplicated: \['cam0'\]"),
    "session.toml cameras not a list": (write_text("session.toml", 'cameras = "cam0"\n'), DETECT,
                                        r"session.toml: cameras must be a list of folder names, got 'cam0'"),
    "session.toml unknown laser mode": (write_text("session.toml", 'laser_mode = "blob"\n'), DETECT,
                                        r"mode must be one of \('spot', 'stripe'\), got 'blob'"),
    "--resume with other options": (no_change, DETECT + ["--resume", "--mode", "stripe"],
                                    r"traces.parquet: was made with options \{'mode': 'spot', .*\}, not "
                                    r"\{'mode': 'stripe', .*\}; run without --resume to start again"),
    "--resume over a corrupt traces file": (write_bytes("traces.parquet", b"junk"), DETECT + ["--resume"],
                                            r"traces.parquet: not a readable Parquet file"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_detect_options_bad_input(good_session, capsys, case):
    setup, argv, message = CASES[case]
    setup(good_session)
    capsys.readouterr()
    argv = [a.format(s=good_session) for a in argv]
    assert_fails_cleanly(argv, message, good_session, capsys)

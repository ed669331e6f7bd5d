"""Bad-input matrix, part: `scanrig detect` and the command line itself."""

import numpy as np
import pytest

from scanrig.io.session import write_image
from tests.reliability.matrix import assert_fails_cleanly


@pytest.fixture
def session(tmp_path):
    """Two cameras, two frames each, and a traces.parquet from an earlier good run."""
    img = np.full((48, 64), 10, np.uint8)
    img[20:23, 30:33] = 200
    for cam in ("cam0", "cam1"):
        (tmp_path / "scan" / cam).mkdir(parents=True)
        for stem in ("f0", "f1"):
            write_image(tmp_path / "scan" / cam / f"{stem}.png", img)
    from scanrig.cli.main import main
    assert main(["detect", str(tmp_path), "--mode", "spot"]) == 0
    assert (tmp_path / "traces.parquet").exists()
    return tmp_path


def corrupt(data=b"\x89PNG\r\n\x1a\nnot really", name="cam1/f1.png"):
    return lambda s: (s / "scan" / name).write_bytes(data)


def write_text(name, text):
    return lambda s: (s / name).write_text(text)


def replace_frame(shape, dtype):
    return lambda s: write_image(s / "scan" / "cam0" / "f1.png", np.zeros(shape, dtype))


def no_change(s):
    return None


DETECT = ["detect", "{s}"]
#: case -> (setup on the good session, argv with {s} for the session, expected error line)
CASES = {
    "missing session folder": (no_change, ["detect", "{s}/nope"], r"nope: session folder not found"),
    "no scan folder": (lambda s: (s / "scan").rename(s / "scan_old"), DETECT, r"scan: scan folder not found in session"),
    "truncated image": (corrupt(), DETECT, r"cam1/f1.png: cannot decode image \(unreadable or truncated file\)"),
    "empty image file": (corrupt(b"", "cam0/f0.png"), DETECT, r"cam0/f0.png: image file is empty"),
    "unknown mode": (no_change, DETECT + ["--mode", "blob"], r"mode must be one of \('spot', 'stripe'\), got 'blob'"),
    "frame of another size": (replace_frame((10, 10), np.uint8), DETECT,
                              r"cam0/f1.png: frame is 10x10 8-bit grey but f0.png of camera 'cam0' is 64x48 8-bit grey"),
    "frame of another bit depth": (replace_frame((48, 64), np.uint16), DETECT,
                                   r"cam0/f1.png: frame is 64x48 16-bit grey but f0.png of camera 'cam0' is 64x48 8-bit grey"),
    "camera named in session.toml missing": (write_text("session.toml", 'cameras = ["cam0", "cam7"]\n'), DETECT,
                                             r"camera folders \['cam7'\] named in session.toml are missing"),
    "session.toml misspelt key": (write_text("session.toml", 'camras = ["cam0"]\n'), DETECT,
                                  r"session.toml: top level: unknown field 'camras' \(did you mean 'cameras'\?\)"),
    "session.toml not TOML": (write_text("session.toml", "cameras = [\n"), DETECT, r"session.toml: not valid TOML"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_detect_bad_input(session, capsys, case):
    setup, argv, message = CASES[case]
    setup(session)
    capsys.readouterr()
    argv = [a.format(s=session) for a in argv]
    assert_fails_cleanly(argv, message, session, capsys)

"""Session store: manifest round trip, torn tails, corrupt logs, refusal to overwrite."""

import json

import numpy as np
import pytest

from scanrig.errors import FileFormatError, InputError
from scanrig.scan.protocol import Beam
from scanrig.scan.store import MANIFEST_NAME, ScanStore, frame_stem

CAMERAS = ["cam0", "cam10", "cam2"]


def _beams(rng, n):
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return [Beam(rng.normal(size=3), di) for di in d]


def _images(rng):
    return {c: rng.integers(0, 255, (6, 8), dtype=np.uint8) for c in CAMERAS}


@pytest.fixture
def store(tmp_path):
    rng = np.random.default_rng(7)
    s = ScanStore.create(tmp_path, CAMERAS, {"seed": 5, "spacing_mm": 2.0})
    s.add_pass(0, _beams(rng, 3), rng.normal(size=(3, 3)), rng.bit_generator.state)
    for _ in range(2):
        s.add_frame(_images(rng))
    return s


def test_reopen_gives_the_same_state(store, tmp_path):
    again = ScanStore.open(tmp_path)
    assert again.state.frames == ["f000000", "f000001"]
    assert again.state.beams == store.state.beams
    np.testing.assert_array_equal(again.state.aims_m, store.state.aims_m)
    assert again.state.passes[0].rng_after == store.state.passes[0].rng_after
    assert again.state.pending == store.state.beams[2:]
    assert again.state.config == {"seed": 5, "spacing_mm": 2.0}
    assert again.state.cameras == CAMERAS


def test_frames_and_beams_csv_are_written(store, tmp_path):
    for stem, by_cam in store.frame_paths().items():
        assert sorted(p.name for p in by_cam.values()) == [f"{stem}.png"] * 3
        assert all(p.is_file() for p in by_cam.values())
    rows = (tmp_path / "scan" / "beams.csv").read_text().splitlines()
    assert rows[0].startswith("frame,pass,origin_x_m")
    assert [r.split(",")[0] for r in rows[1:]] == ["f000000", "f000001"]
    assert Beam.from_row([float(x) for x in rows[2].split(",")[2:]]) == store.state.beams[1]


def test_beam_rows_round_trip_exactly():
    rng = np.random.default_rng(11)
    for beam in _beams(rng, 20):
        assert Beam.from_row(beam.as_row()) == beam
        stripe = Beam(beam.origin, beam.direction, np.cross(beam.direction, [0, 0, 1]) / np.linalg.norm(np.cross(beam.direction, [0, 0, 1])))
        assert Beam.from_row(stripe.as_row()) == stripe


def test_torn_last_line_is_dropped_and_truncated(store, tmp_path):
    manifest = tmp_path / "scan" / MANIFEST_NAME
    good = manifest.read_bytes()
    manifest.write_bytes(good + b'0badc0de {"kind":"frame","ind')     # killed mid-append
    again = ScanStore.open(tmp_path)
    assert again.state.frames == ["f000000", "f000001"]
    assert manifest.read_bytes() == good


def test_checksum_mismatch_on_last_line_is_a_torn_tail(store, tmp_path):
    manifest = tmp_path / "scan" / MANIFEST_NAME
    lines = manifest.read_text().splitlines(keepends=True)
    manifest.write_text("".join(lines[:-1]) + lines[-1].replace("f000001", "f000009"))
    assert ScanStore.open(tmp_path).state.frames == ["f000000"]


def test_corrupt_middle_line_is_an_error(store, tmp_path):
    manifest = tmp_path / "scan" / MANIFEST_NAME
    lines = manifest.read_text().splitlines(keepends=True)
    lines[1] = lines[1].replace('"pass":0', '"pass":1')
    manifest.write_text("".join(lines))
    with pytest.raises(FileFormatError, match=r"manifest.jsonl: line 2 is corrupt \(checksum mismatch\) and is not the last line"):
        ScanStore.open(tmp_path)


def test_create_refuses_an_existing_scan(store, tmp_path):
    with pytest.raises(InputError, match=r"manifest.jsonl already exists: pass --resume to continue that scan"):
        ScanStore.create(tmp_path, CAMERAS, {})


def test_open_without_manifest(tmp_path):
    with pytest.raises(FileFormatError, match=r"scan/manifest.jsonl: no scan manifest to resume"):
        ScanStore.open(tmp_path)


def test_manifest_lines_are_checksummed_json(store, tmp_path):
    import zlib

    for line in (tmp_path / "scan" / MANIFEST_NAME).read_bytes().splitlines():
        crc, payload = line.split(b" ", 1)
        assert int(crc, 16) == zlib.crc32(payload)
        json.loads(payload)


def test_frame_stems_are_zero_padded():
    assert frame_stem(0) == "f000000"
    assert frame_stem(123) == "f000123"


def test_bad_beams():
    from scanrig.errors import ShapeError

    with pytest.raises(InputError, match=r"beam direction must be a unit vector, got norm 2"):
        Beam(np.zeros(3), np.array([0.0, 0.0, 2.0]))
    with pytest.raises(InputError, match=r"beam fan_axis must be perpendicular to direction, got dot 0.6"):
        Beam(np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([0.8, 0.0, 0.6]))
    with pytest.raises(ShapeError, match=r"beam origin must have shape \(3,\), got \(2,\)"):
        Beam(np.zeros(2), np.array([0.0, 0.0, 1.0]))
    with pytest.raises(InputError, match=r"a beam row has 9 numbers \(origin, direction, fan axis\), got shape \(6,\)"):
        Beam.from_row(np.zeros(6))


def test_scan_killed_while_starting(tmp_path):
    manifest = tmp_path / "scan" / MANIFEST_NAME
    manifest.parent.mkdir()
    manifest.write_bytes(b'1234abcd {"kind":"sta')
    with pytest.raises(FileFormatError, match=r"the first record must be the scan's start record \(a scan killed while starting"):
        ScanStore.open(tmp_path)

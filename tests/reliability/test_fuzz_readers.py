"""Fuzzing the file readers beyond the foundation: any input loads or raises the documented error.

Readers: scene TOML (:func:`scanrig.sim.scene_file.load_scene_file`), PLY
(:func:`scanrig.io.ply.read_ply`), ``traces.parquet`` (:func:`scanrig.laser.traces.read_traces`),
the scan manifest (:func:`scanrig.scan.store.read_state`) and the design spec
(:func:`scanrig.design.spec.load_spec`). Inputs are mutations of a valid file (see
:mod:`tests.reliability.test_fuzz_foundation_readers`) and raw bytes. Anything but success or
:class:`~scanrig.errors.InputError` is a crash. Each example takes a few milliseconds (a file
write, a parse, for scenes the meshes), so the suite runs 400 examples per reader (50 for
scenes); the environment variable ``SCANRIG_FUZZ_EXAMPLES`` sets one count for all, and the
acceptance run uses ``SCANRIG_FUZZ_EXAMPLES=2000``.
"""

import json
import os
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from scanrig.errors import InputError
from tests.reliability.test_fuzz_foundation_readers import mutated


def fuzz(n: int):
    n = int(os.environ.get("SCANRIG_FUZZ_EXAMPLES", n))
    return settings(max_examples=n, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def raw_text(max_size=300):
    return st.binary(max_size=max_size).map(lambda b: b.decode("latin-1"))


def write(path, text: str):
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    return path


SCENE_TEXT = """name = "fuzz"
center_m = [0.0, 0.0, 0.1]
radius_m = 0.2
[lighting]
ambient_W_m2 = 40.0
[rig]
distance_m = 1.0
[laser]
head_m = [0.3, -0.75, 0.75]
[sensor]
bit_depth = 12
[materials.paint]
kind = "matte"
albedo = 0.7
[[objects]]
name = "ball"
shape = "sphere"
radius_m = 0.1
material = "paint"
position_m = [0.0, 0.0, 0.1]
rotation_deg = [0.0, 0.0, 30.0]
[[objects]]
name = "block"
shape = "box"
size_m = [0.1, 0.1, 0.05]
material = "paint"
"""


@fuzz(50)
@given(text=st.one_of(mutated(SCENE_TEXT), raw_text()))
def test_scene_file_reader_never_crashes(tmp_path, text):
    from scanrig.sim.scene_file import load_scene_file

    try:
        load_scene_file(write(tmp_path / "scene.toml", text))
    except InputError:
        pass


SPEC_TEXT = """[camera]
width_px = 1280
height_px = 1024
pixel_pitch_m = 4.8e-6
focal_lengths_m = [0.012, 0.016]
f_number = 4.0
circle_of_confusion_px = 2.0
[mounting]
shape = "cylinder"
radius_m = [0.8, 1.2]
height_m = [0.0, 0.6]
elevation_deg = [10.0, 60.0]
look_at = [0.0, 0.0, 0.1]
up = [0.0, 0.0, 1.0]
n_candidates = 50
[laser]
mode = "spot"
sigma_px = 0.3
wavelength_m = 650e-9
speckle_contrast = 1.0
step_m = 1e-3
[target]
sigma_m = 5e-4
min_views = 2
max_incidence_deg = 75.0
[calibration]
rotation_sigma_rad = 0.0
translation_sigma_m = 0.0
"""


@fuzz(400)
@given(text=st.one_of(mutated(SPEC_TEXT), raw_text()))
def test_design_spec_reader_never_crashes(tmp_path, text):
    from scanrig.design.spec import load_spec

    try:
        load_spec(write(tmp_path / "spec.toml", text))
    except InputError:
        pass


@pytest.fixture(scope="module")
def ply_files(tmp_path_factory):
    """A binary points.ply and an ASCII mesh PLY with faces, as bytes."""
    from scanrig.io.ply import write_ply

    folder = tmp_path_factory.mktemp("ply")
    rng = np.random.default_rng(3)
    vertices = {"x": rng.normal(size=6), "y": rng.normal(size=6), "z": rng.normal(size=6),
                "flags": np.arange(6, dtype=np.uint16)}
    write_ply(folder / "b.ply", vertices, comments=("units: metres",))
    write_ply(folder / "a.ply", vertices, faces=np.array([[0, 1, 2], [3, 4, 5]]), binary=False)
    return [(folder / name).read_bytes() for name in ("b.ply", "a.ply")]


@fuzz(400)
@given(data=st.data())
def test_ply_reader_never_crashes(tmp_path, ply_files, data):
    from scanrig.io.ply import read_ply

    raw = bytearray(data.draw(st.sampled_from(ply_files)))
    header_end = raw.index(b"end_header") + len(b"end_header\n")
    if data.draw(st.booleans()):       # mutate a header line: the format, counts, types, names
        lines = raw[:header_end].decode("ascii").splitlines()
        i = data.draw(st.integers(1, len(lines) - 1))
        words = lines[i].split(" ")
        j = data.draw(st.integers(0, len(words) - 1))
        words[j] = data.draw(st.sampled_from(["0", "-1", "99999999", "float", "uchar", "list", "int", "vertex",
                                              "face", "x", "binary_big_endian", "ascii", "", "1.5", "\x00"]))
        lines[i] = " ".join(words)
        raw = bytearray(("\n".join(lines) + "\n").encode("latin-1")) + raw[header_end:]
    for i, b in data.draw(st.lists(st.tuples(st.integers(0, len(raw) - 1), st.integers(0, 255)), max_size=3)):
        raw[i] = b
    path = tmp_path / "f.ply"
    path.write_bytes(bytes(raw[: data.draw(st.integers(0, len(raw)))]))
    try:
        vertices, faces, _ = read_ply(path)
        assert {"x", "y", "z"} <= set(vertices)
    except InputError:
        pass


@pytest.fixture(scope="module")
def traces_bytes(tmp_path_factory):
    from scanrig.laser.traces import make_table, write_traces

    rng = np.random.default_rng(4)
    n = 5
    columns = {"u": rng.uniform(0, 64, n), "v": rng.uniform(0, 48, n), "sigma_px": np.full(n, 0.1),
               "peak": rng.uniform(50, 200, n), "width_px": np.full(n, 2.0), "snr": rng.uniform(10, 50, n),
               "rank": np.arange(n), "cov_uu": np.full(n, 0.01), "cov_uv": np.zeros(n), "cov_vv": np.full(n, 0.01),
               "line": np.zeros(n), "saturated": np.zeros(n, bool)}
    path = tmp_path_factory.mktemp("traces") / "traces.parquet"
    table = make_table("spot", columns, camera="cam0", frame="f0")
    write_traces(path, table, {"format_version": 1, "frames_done": [["cam0", "f0"]]})
    return path.read_bytes()


@fuzz(400)
@given(data=st.data())
def test_traces_reader_never_crashes(tmp_path, traces_bytes, data):
    from scanrig.laser.traces import read_traces

    raw = bytearray(traces_bytes)
    for i, b in data.draw(st.lists(st.tuples(st.integers(0, len(raw) - 1), st.integers(0, 255)), max_size=4)):
        raw[i] = b
    path = tmp_path / "traces.parquet"
    path.write_bytes(bytes(raw[: data.draw(st.integers(0, len(raw)))]))
    try:
        read_traces(path)
    except InputError:
        pass


def manifest_line(record) -> bytes:
    payload = json.dumps(record, separators=(",", ":")).encode()
    return b"%08x " % zlib.crc32(payload) + payload + b"\n"


MANIFEST = [
    {"kind": "start", "format_version": 1, "cameras": ["cam0", "cam1"], "config": {"seed": 1}},
    {"kind": "dark", "files": {"cam0": "cam0/dark.png", "cam1": "cam1/dark.png"}},
    {"kind": "pass", "pass": 0, "first_frame": 0, "rng_after": {"state": 1},
     "aims_m": [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]],
     "beams": [{"origin": [0.0, 0.0, 0.3], "direction": [0.0, 0.0, -1.0], "fan_axis": None},
               {"origin": [0.0, 0.0, 0.3], "direction": [0.1, 0.0, -0.99], "fan_axis": [1.0, 0.0, 0.0]}]},
    {"kind": "frame", "index": 0, "frame": "00000"},
    {"kind": "frame", "index": 1, "frame": "00001"},
    {"kind": "done", "reason": "budget"},
]
json_values = st.one_of(st.none(), st.booleans(), st.integers(-3, 3), st.floats(), st.text(max_size=4),
                        st.lists(st.integers(-1, 2), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(),
                                                                                  max_size=2))


@st.composite
def mutated_manifest(draw):
    """Records with a key dropped or a value replaced, checksummed again (as a newer or older
    scanrig, or a hand edit, would write them), some lines dropped or swapped, a torn end."""
    records = json.loads(json.dumps(MANIFEST))
    for _ in range(draw(st.integers(1, 3))):
        rec = records[draw(st.integers(0, len(records) - 1))]
        if not rec:
            continue
        key = draw(st.sampled_from(sorted(rec)))
        if draw(st.booleans()):
            del rec[key]
        else:
            rec[key] = draw(json_values)
    if draw(st.booleans()):
        i, j = draw(st.integers(0, len(records) - 1)), draw(st.integers(0, len(records) - 1))
        records[i], records[j] = records[j], records[i]
    data = b"".join(manifest_line(r) for r in records)
    return data[: draw(st.integers(len(data) // 2, len(data)))]


@fuzz(400)
@given(data=st.one_of(mutated_manifest(), st.binary(max_size=300)))
def test_scan_manifest_reader_never_crashes(tmp_path, data):
    from scanrig.scan.store import read_state

    (tmp_path / "scan").mkdir(exist_ok=True)
    (tmp_path / "scan" / "manifest.jsonl").write_bytes(data)
    try:
        read_state(tmp_path)
    except InputError:
        pass

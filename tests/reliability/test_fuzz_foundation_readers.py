"""Fuzzing the foundation's file readers: any input either loads or raises the documented error.

Each reader gets >= 2,000 examples (issue 10): mutations of a valid file (lines dropped,
duplicated or swapped, values replaced by other TOML values, random bytes spliced in) and raw
random bytes. Anything but success or :class:`InputError` (a ``ValueError``) is a crash.
"""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import scanrig
from scanrig.errors import InputError
from scanrig.geometry import Camera, Rig, RigidTransform
from scanrig.io.opencv_yaml import export_opencv_yaml, import_opencv_yaml
from scanrig.io.rig_file import rig_to_toml
from scanrig.io.session import Session, read_image, write_image

FUZZ = settings(max_examples=2000, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

toml_values = st.one_of(
    st.integers(-10**6, 10**6).map(str), st.floats(allow_nan=True).map(lambda f: repr(f).replace("inf", "inf")),
    st.text(max_size=8).map(lambda s: '"' + s.replace("\\", "").replace('"', "") + '"'),
    st.lists(st.floats(-1e3, 1e3), max_size=13).map(lambda v: "[" + ", ".join(map(repr, v)) + "]"),
    st.just("[[1.0, 0.0], [0.0]]"), st.just("true"), st.just("{a = 1}"),
)


def valid_rig_text() -> str:
    cams = [Camera(f"cam{i}", "opencv5", [1000.0, 1000.0, 640.0, 512.0, -0.1, 0.01, 0.0, 0.0, 0.0], 1280, 1024,
                   RigidTransform.from_rvec_tvec([0.0, 0.1 * i, 0.0], [0.0, 0.0, 1.0])) for i in range(2)]
    return rig_to_toml(Rig(cams), camera_info={"cam0": {"rms_px": 0.1}}, metadata={"seed": 1})


@st.composite
def mutated(draw, text: str):
    lines = text.splitlines()
    for _ in range(draw(st.integers(1, 3))):
        i = draw(st.integers(0, len(lines) - 1))
        op = draw(st.sampled_from(["drop", "dup", "swap", "value", "bytes"]))
        if op == "drop":
            lines.pop(i)
        elif op == "dup":
            lines.insert(i, lines[i])
        elif op == "swap":
            j = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
        elif op == "value" and "=" in lines[i]:
            lines[i] = lines[i].split("=", 1)[0] + "= " + draw(toml_values)
        else:
            junk = draw(st.text(max_size=6))
            k = draw(st.integers(0, len(lines[i])))
            lines[i] = lines[i][:k] + junk + lines[i][k:]
        if not lines:
            break
    return "\n".join(lines) + "\n"


RIG_TEXT = valid_rig_text()


@FUZZ
@given(text=st.one_of(mutated(RIG_TEXT), st.binary(max_size=200).map(lambda b: b.decode("latin-1"))))
def test_rig_toml_reader_never_crashes(tmp_path, text):
    path = tmp_path / "rig.toml"
    path.write_bytes(text.encode("utf-8", "surrogatepass"))
    try:
        scanrig.load_rig(path)
    except InputError:
        pass


SESSION_TEXT = 'cameras = ["a", "b"]\nlaser_color = "red"\nlaser_mode = "spot"\nseed = 3\n'


@FUZZ
@given(text=mutated(SESSION_TEXT))
def test_session_toml_reader_never_crashes(tmp_path, text):
    for cam in ("a", "b"):
        (tmp_path / "scan" / cam).mkdir(parents=True, exist_ok=True)
    (tmp_path / "session.toml").write_text(text)
    try:
        Session(tmp_path).camera_names("scan")
    except InputError:
        pass


@pytest.fixture(scope="module")
def png_bytes(tmp_path_factory):
    path = tmp_path_factory.mktemp("img") / "x.png"
    write_image(path, (np.arange(64 * 48, dtype=np.uint16).reshape(48, 64) % 251).astype(np.uint8))
    return path.read_bytes()


@FUZZ
@given(data=st.data())
def test_image_reader_never_crashes(tmp_path, png_bytes, data):
    raw = bytearray(png_bytes)
    cut = data.draw(st.integers(0, len(raw)))
    flips = data.draw(st.lists(st.tuples(st.integers(0, len(raw) - 1), st.integers(0, 255)), max_size=4))
    for i, b in flips:
        raw[i] = b
    path = tmp_path / "f.png"
    path.write_bytes(bytes(raw[:cut]))
    try:
        img = read_image(path)
        assert img.dtype in (np.uint8, np.uint16)
    except InputError:
        pass


@pytest.fixture(scope="module")
def yaml_text(tmp_path_factory):
    path = tmp_path_factory.mktemp("yml") / "rig.yml"
    rig_path = tmp_path_factory.mktemp("rig") / "rig.toml"
    rig_path.write_text(RIG_TEXT)
    export_opencv_yaml(scanrig.load_rig(rig_path), path)
    return path.read_text()


@FUZZ
@given(data=st.data())
def test_opencv_yaml_reader_never_crashes(tmp_path, yaml_text, data):
    lines = yaml_text.splitlines()
    for _ in range(data.draw(st.integers(1, 3))):
        i = data.draw(st.integers(1, len(lines) - 1))
        op = data.draw(st.sampled_from(["drop", "value", "junk"]))
        if op == "drop":
            lines.pop(i)
        elif op == "value" and ":" in lines[i]:
            lines[i] = lines[i].split(":", 1)[0] + ": " + data.draw(st.sampled_from(["-1", "abc", "[ 1., 2. ]", "1e400", ""]))
        else:
            lines[i] = lines[i] + data.draw(st.text(max_size=4))
        if len(lines) < 2:
            break
    path = tmp_path / "rig.yml"
    path.write_text("\n".join(lines) + "\n")
    try:
        import_opencv_yaml(path)
    except InputError:
        pass

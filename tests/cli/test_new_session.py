"""Verbs that create a session refuse a non-empty folder; ``--force`` replaces only their own files."""

import re

import pytest

from scanrig.cli.main import main
from tests.sim.test_session import SMALL_SCENE

#: A one-camera, two-frame session of a small plane without calibration shots (~1 s).
TINY = ["--cameras", "1", "--frames", "2", "--no-calibration", "--workers", "1"]


def _state(root):
    """Every entry below ``root`` (folders too) and every file's bytes."""
    return {str(p.relative_to(root)): p.read_bytes() if p.is_file() else None for p in sorted(root.rglob("*"))}


@pytest.fixture
def scene(tmp_path):
    path = tmp_path / "small.toml"
    path.write_text(SMALL_SCENE)
    return path


@pytest.fixture
def occupied(tmp_path):
    """A folder holding a user's notes and a scan image of another session."""
    root = tmp_path / "mine"
    (root / "scan" / "cam0").mkdir(parents=True)
    (root / "notes.txt").write_text("measurements of the 3rd of May\n")
    (root / "scan" / "cam0" / "00000.png").write_bytes(b"not simulated")
    (root / "session.toml").write_text('cameras = ["cam0"]\n')
    return root


def _refused(argv, root, verb, capsys, force_hint=True):
    before = _state(root)
    assert main(argv) == 2
    err = capsys.readouterr().err.splitlines()
    hint = ", or --force to replace the files it writes \\(nothing is deleted\\)" if force_hint else ""
    assert len(err) == 1 and re.fullmatch(
        rf"error: {re.escape(str(root))} is not empty \(it holds notes.txt, scan/, session.toml\) and "
        rf"scanrig {verb} would overwrite files there; give a new or empty folder{hint}", err[0]), err
    assert _state(root) == before


def test_simulate_refuses_a_non_empty_folder(occupied, scene, capsys):
    _refused(["simulate", str(occupied), "--scene", str(scene), *TINY], occupied, "simulate", capsys)


def test_simulate_refusal_lists_the_first_entries(tmp_path, scene, capsys):
    root = tmp_path / "many"
    root.mkdir()
    for name in ("b.txt", "a10.txt", "a2.txt", "c.txt", "d.txt", "e.txt"):
        (root / name).write_text(name)
    assert main(["simulate", str(root), "--scene", str(scene), *TINY]) == 2
    assert f"{root} is not empty (it holds a2.txt, a10.txt, b.txt, c.txt and 2 more)" in capsys.readouterr().err


def test_simulate_writes_into_an_empty_folder(tmp_path, scene, capsys):
    root = tmp_path / "empty"
    root.mkdir()
    assert main(["simulate", str(root), "--scene", str(scene), *TINY]) == 0
    assert (root / "scan" / "cam0" / "00001.png").is_file()
    assert "--force" not in capsys.readouterr().out


def test_simulate_force_replaces_only_its_own_files(occupied, scene, capsys):
    foreign = {name: (occupied / name).read_bytes() for name in ("notes.txt", "scan/cam0/00000.png")}
    (occupied / "scan" / "cam0" / "00007.png").write_bytes(b"a frame of an earlier, longer run")
    assert main(["simulate", str(occupied), "--scene", str(scene), *TINY, "--seed", "3", "--force"]) == 0
    out = capsys.readouterr().out
    # simulate writes scan/cam0/00000.png and session.toml: replaced; the other two are not its files
    assert (occupied / "scan" / "cam0" / "00000.png").read_bytes() != foreign["scan/cam0/00000.png"]
    assert "seed = 3" in (occupied / "session.toml").read_text()
    assert (occupied / "notes.txt").read_bytes() == foreign["notes.txt"]
    assert (occupied / "scan" / "cam0" / "00007.png").read_bytes() == b"a frame of an earlier, longer run"
    assert (f"--force: replaced 2 of the 4 files that were in {occupied}; kept 2 it does not write: "
            f"notes.txt, scan/cam0/00007.png") in out


def test_simulate_force_twice_gives_the_same_files(tmp_path, scene):
    root = tmp_path / "s"
    assert main(["simulate", str(root), "--scene", str(scene), *TINY, "--seed", "5"]) == 0
    first = _state(root)
    assert main(["simulate", str(root), "--scene", str(scene), *TINY, "--seed", "5", "--force"]) == 0
    assert _state(root) == first


def test_demo_refuses_a_non_empty_folder(occupied, capsys):
    _refused(["demo", "--out", str(occupied), "--quick"], occupied, "demo", capsys, force_hint=False)


def test_scan_refusing_a_scanned_folder_writes_no_rig(occupied, capsys):
    before = _state(occupied)
    assert main(["scan", str(occupied), "--sim", "sphere", "--budget", "2", "--sim-scale", "0.25"]) == 2
    assert "already holds camera folders but no manifest" in capsys.readouterr().err
    assert _state(occupied) == before

"""Verbs that consume a session's product also take the session folder, and no stage verb
changes its inputs."""

import re

import pytest

from scanrig.cli.main import main
from tests.reliability.matrix import snapshot

#: Stage verbs in pipeline order on the good session, with the files each one writes (its outputs
#: may be replaced; every other file must keep its bytes).
STAGES = (
    (["detect", "{s}", "--mode", "spot"], {"traces.parquet"}),
    (["reconstruct", "{s}", "--out", "{s}/points_again.ply"], {"points_again.ply"}),
    (["filter", "{s}", "--seed", "1", "--architecture", "ridge"], {"surface.ply", "mesh.ply", "filter_summary.json"}),
    (["evaluate", "{s}"], {"points_distances.png"}),
    (["report", "{s}", "--max-points", "100"], {"report.html"}),
    (["export", "{s}", "--format", "obj"], {"export/obj/points.obj", "export/obj/surface.obj",
                                           "export/obj/mesh.obj"}),
)


def _argv(argv, session):
    return [a.replace("{s}", str(session)) for a in argv]


@pytest.mark.slow
def test_stage_verbs_leave_their_inputs_unchanged(good_session, capsys):
    """Each verb is given the session folder (filter and evaluate read its points.ply)."""
    for argv, outputs in STAGES:
        before = snapshot(good_session)
        assert main(_argv(argv, good_session)) == 0, capsys.readouterr().err
        after = snapshot(good_session)
        changed = {path for path in before if after.get(path) != before[path]}
        assert changed <= outputs, f"scanrig {argv[0]} changed its inputs {sorted(changed - outputs)}"
        assert set(after) - set(before) <= outputs, f"scanrig {argv[0]} wrote {sorted(set(after) - set(before))}"
        assert set(after) >= outputs


def test_evaluate_takes_the_session_folder(good_session, capsys):
    def figures(printed: str) -> str:   # from the first figure on (the progress lines before it give times)
        return printed[printed.index("20 points: RMS"):]

    assert main(["evaluate", str(good_session / "points.ply"), "--truth", str(good_session / "truth")]) == 0
    by_file = figures(capsys.readouterr().out)
    assert main(["evaluate", str(good_session), "--rig", str(good_session)]) == 0
    assert figures(capsys.readouterr().out) == by_file


def test_reconstruct_takes_another_session_as_its_rig(good_session, tmp_path, capsys):
    other = tmp_path / "calibrated"
    other.mkdir()
    (other / "rig.toml").write_bytes((good_session / "rig.toml").read_bytes())
    assert main(["reconstruct", str(good_session), "--rig", str(other), "--out", str(tmp_path / "a.ply")]) == 0
    assert main(["reconstruct", str(good_session), "--out", str(tmp_path / "b.ply")]) == 0
    assert f"comment rig: {other / 'rig.toml'}\n" in (tmp_path / "a.ply").read_bytes().decode("latin-1")
    body = [re.sub(rb"comment (command|rig): [^\n]*\n", b"", (tmp_path / name).read_bytes())
            for name in ("a.ply", "b.ply")]
    assert body[0] == body[1]


def test_target_print_takes_the_session_folder(good_session, tmp_path, capsys):
    from scanrig.targets import chessboard, save_target

    save_target(chessboard((5, 4), 0.02), good_session / "target.toml")
    assert main(["target", "print", str(good_session), "--out", str(tmp_path / "prints")]) == 0
    assert (tmp_path / "prints" / "board.svg").is_file()


@pytest.mark.parametrize("argv, product, producer", [
    (["filter", "{s}"], "points.ply", "scanrig reconstruct"),
    (["evaluate", "{s}"], "points.ply", "scanrig reconstruct"),
    (["reconstruct", "{s}", "--rig", "{s}/truth/meshes"], "rig.toml", "scanrig calibrate"),
])
def test_a_session_folder_without_the_product_is_named(good_session, capsys, argv, product, producer):
    (good_session / "points.ply").unlink()
    folder = good_session / "truth" / "meshes" if "--rig" in argv else good_session
    before = snapshot(good_session)
    assert main(_argv(argv, good_session)) == 2
    expected = f"error: {folder}: session folder holds no {product} ({producer} writes it)"
    assert capsys.readouterr().err.strip() == expected
    assert snapshot(good_session) == before


@pytest.mark.slow
def test_calibrate_leaves_its_inputs_unchanged(tmp_path, capsys):
    """A one-camera chessboard session (6 poses, 800 x 640, with laser-on twins in light_plane/):
    only rig.toml and calibration_report/ may appear."""

    from tests.reconstruct.light_plane_synth import rendered_session

    root = tmp_path / "s"
    root.mkdir()
    rendered_session(root, 6)
    before = snapshot(root)
    assert main(["calibrate", str(root), "--no-cross-validate", "--no-plots"]) == 0, capsys.readouterr().err
    after = snapshot(root)
    assert {path: after.get(path) for path in before} == before
    assert {path.split("/")[0] for path in set(after) - set(before)} == {"rig.toml", "calibration_report"}

"""Progress of long commands in a log: plain lines with counts when stdout is not a terminal."""

import re

from scanrig.cli.progress import stage_progress


def test_plain_lines_name_each_stage_with_its_counts(capsys, monkeypatch):
    clock = iter([0.0, 1.0, 6.5, 7.0, 7.0, 8.0, 9.5])  # monotonic seconds, one per reading
    monkeypatch.setattr("scanrig.cli.progress.time.monotonic", lambda: next(clock))
    with stage_progress(plain=True, interval_s=5.0) as progress:
        progress("frames", 1, 4)   # t = 1: the stage starts (it began at t = 0)
        progress("frames", 2, 4)   # t = 6.5: 5 s since the last line
        progress("frames", 4, 4)   # t = 7: done
        progress("fitting", 3, None)  # t = 8: a stage of unknown total
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "frames: started, 4 to do"
    assert re.fullmatch(r"frames: 2/4, 0\.31/s, about 6 s left", out[1])
    assert out[2] == "frames: done, 4/4 in 7.0 s"
    assert out[3] == "fitting: started"
    assert out[4] == "fitting: done, 3 in 2.5 s"
    assert len(out) == 5


def test_no_line_between_reports_closer_than_the_interval(capsys, monkeypatch):
    times = iter([0.0] + [0.1 * k for k in range(1, 40)])
    monkeypatch.setattr("scanrig.cli.progress.time.monotonic", lambda: next(times))
    with stage_progress(plain=True, interval_s=5.0) as progress:
        for done in range(1, 30):
            progress("frames", done, 100)
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "frames: started, 100 to do" and lines[-1].startswith("frames: done, 29/100")
    assert len(lines) == 2


def test_simulate_into_a_log_prints_its_stages_with_counts(tmp_path, capsys):
    """``scanrig simulate`` with stdout not a terminal (as under pytest): plain lines per stage."""
    from scanrig.cli.main import main
    from tests.sim.test_session import SMALL_SCENE

    scene = tmp_path / "small.toml"
    scene.write_text(SMALL_SCENE)
    argv = ["simulate", str(tmp_path / "s"), "--scene", str(scene), "--cameras", "1", "--frames", "2",
            "--no-calibration", "--workers", "1"]
    assert main(argv) == 0
    out = capsys.readouterr().out.splitlines()
    assert "frames: started, 2 to do" in out
    assert any(re.fullmatch(r"frames: done, 2/2 in \d+\.\d s", line) for line in out)


def test_bars_on_a_terminal_end_complete_with_their_counts():
    """On a terminal: one bar per stage, each shown complete with its count once the next stage (or
    the command) is done; a stage of unknown total is never shown as 0/None."""
    import io

    from rich.console import Console

    screen = io.StringIO()
    with stage_progress(Console(file=screen, force_terminal=True, width=100), plain=False) as progress:
        progress("frames", 1, 4)
        progress("frames", 4, 4)
        progress("fitting", 2, None)
        progress("fitting", 5, None)
    text = re.sub(r"\x1b\[[0-9;?]*[A-Za-z]", "", screen.getvalue())
    assert "4/4" in text and "5/5" in text and "None" not in text


def test_evaluate_into_a_log_prints_each_step(tmp_path, capsys):
    """``scanrig evaluate`` with stdout not a terminal: a start and an end line for each step, then
    the figures."""
    import numpy as np
    import trimesh

    from scanrig.cli.main import main
    from scanrig.reconstruct.points import PointCloud, write_points

    (tmp_path / "truth" / "meshes").mkdir(parents=True)
    trimesh.creation.box(extents=(0.2, 0.2, 0.2)).export(tmp_path / "truth" / "meshes" / "box.ply")
    p = np.array([[0.0, 0.0, 0.1005], [0.0, 0.0, -0.1002], [0.1, 0.0, 0.0]])
    write_points(tmp_path / "points.ply", PointCloud(p, np.full(3, 1e-4), [2] * 3, [0.1] * 3, range(3), [0] * 3))
    assert main(["evaluate", str(tmp_path / "points.ply")]) == 0
    out = capsys.readouterr().out.splitlines()
    steps = [f"loading the true surface ({tmp_path / 'truth'})", f"measuring {tmp_path / 'points.ply'} and its coverage",
             "writing the histogram"]
    for k, step in enumerate(steps):
        assert out[2 * k] == f"{step}: started"
        assert re.fullmatch(rf"{re.escape(step)}: done in \d+\.\d s", out[2 * k + 1])
    assert out[6].startswith("3 points: RMS ")

"""The scanrig command: version, help, exit codes, usage errors, Ctrl-C."""

import subprocess
import sys

import pytest
import typer

import scanrig
from scanrig.cli.main import main


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"scanrig {scanrig.__version__}"


def test_help_exits_0(capsys):
    assert main(["--help"]) == 0
    assert "calibrate" in capsys.readouterr().out
    assert main(["detect", "--help"]) == 0
    assert "Usage: scanrig detect" in capsys.readouterr().out


def test_no_arguments_shows_help(capsys):
    assert main([]) == 2
    captured = capsys.readouterr()
    assert "calibrate" in captured.out and "Usage: scanrig" in captured.out
    assert captured.err == ""


@pytest.mark.parametrize("argv, lines", [
    (["--bogus"], ["error: No such option: --bogus", "try 'scanrig --help'"]),
    (["detekt"], ["error: No such command 'detekt'. Did you mean 'detect'?", "try 'scanrig --help'"]),
    (["detect"], ["error: Missing argument 'session'.", "try 'scanrig detect --help'"]),
    (["detect", "s", "--workers", "abc"],
     ["error: Invalid value for '--workers': Input should be a valid integer, unable to parse string as an integer",
      "try 'scanrig detect --help'"]),
])
def test_usage_error_is_one_line(capsys, argv, lines):
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.err.splitlines() == lines
    assert captured.out == ""


@pytest.mark.parametrize("interrupt", [KeyboardInterrupt, typer.Abort])
def test_interrupt_prints_interrupted_and_exits_130(monkeypatch, tmp_path, capsys, interrupt):
    def stop(path):
        raise interrupt()

    monkeypatch.setattr("scanrig.targets.load_target", stop)
    assert main(["target", "print", str(tmp_path / "target.toml"), "--out", str(tmp_path / "prints")]) == 130
    assert capsys.readouterr().err == "interrupted\n"


def test_console_script_runs_as_module():
    out = subprocess.run([sys.executable, "-m", "scanrig", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("scanrig ")


@pytest.mark.parametrize("argv, status", [(["--version"], 0), (["detect"], 2)])
def test_console_script_runs_exit_handlers_flushes_and_exits_with_the_status(argv, status):
    code = ("import atexit, sys; atexit.register(lambda: print('handler ran', flush=True)); "
            "from scanrig.cli.main import run; print('buffered', end=''); run(sys.argv[1:])")
    out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True)
    assert out.returncode == status, out.stderr
    assert out.stdout.startswith("buffered") and out.stdout.endswith("handler ran\n")

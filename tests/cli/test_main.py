"""The scanrig command: version, help, exit codes."""

import subprocess
import sys

import scanrig
from scanrig.cli.main import main


def test_version(capsys):
    assert main(["--version"]) == 0
    assert capsys.readouterr().out.strip() == f"scanrig {scanrig.__version__}"


def test_unknown_option_exits_2():
    assert main(["--bogus"]) == 2


def test_console_script_runs_as_module():
    out = subprocess.run([sys.executable, "-m", "scanrig", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.startswith("scanrig ")

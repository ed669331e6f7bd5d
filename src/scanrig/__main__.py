"""``python -m scanrig`` runs the command line."""

from scanrig.cli.main import run

run()

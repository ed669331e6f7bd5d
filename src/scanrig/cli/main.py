"""The ``scanrig`` command line.

Each verb lives in its own module ``scanrig/cli/<verb>.py`` that defines ``command(...)`` with
typer annotations; this module finds them, so adding a verb touches no other file. Verb modules
import their heavy dependencies inside ``command`` so that ``scanrig --help`` starts fast.

Exit status: 0 success; 2 bad input (one line naming the file or argument); 1 internal failure;
130 interrupted.
"""

from __future__ import annotations

import atexit
import importlib
import os
import pkgutil
import sys
import traceback
from typing import NoReturn

import typer

import scanrig
from scanrig.errors import InputError, ScanrigError

#: Verbs in pipeline order for ``--help``; discovered verbs not listed here follow alphabetically.
VERB_ORDER = ("simulate", "calibrate", "relocate", "detect", "reconstruct", "filter", "scan",
              "evaluate", "inspect", "report", "design", "export", "demo")
#: Exit status after Ctrl-C (128 + SIGINT), as shells report it.
INTERRUPTED = 130
ISSUES_HINT = "this is a bug in scanrig; please report it with the command line and the traceback above"


def _version_callback(value: bool):
    if value:
        typer.echo(f"scanrig {scanrig.__version__}")
        raise typer.Exit()


def build_app() -> typer.Typer:
    """The typer application with every verb module found in :mod:`scanrig.cli`."""
    app = typer.Typer(
        name="scanrig",
        help="Multi-camera laser triangulation: calibrate, detect, reconstruct, filter.",
        no_args_is_help=True,
        add_completion=False,
        pretty_exceptions_enable=False,
    )

    @app.callback()
    def _root(
        version: bool = typer.Option(False, "--version", callback=_version_callback, is_eager=True,
                                     help="Print the version and exit."),
    ):
        """Multi-camera laser triangulation: calibrate, detect, reconstruct, filter."""

    package = importlib.import_module("scanrig.cli")
    found = [m.name for m in pkgutil.iter_modules(package.__path__) if m.name not in ("main", "common")]
    rank = {v: i for i, v in enumerate(VERB_ORDER)}
    for name in sorted(found, key=lambda n: (rank.get(n, len(rank)), n)):
        module = importlib.import_module(f"scanrig.cli.{name}")
        if hasattr(module, "command"):
            app.command(name=name)(module.command)
    return app


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status instead of raising ``SystemExit``.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after ``scanrig``; default ``sys.argv[1:]``.

    Returns
    -------
    int
        0 success (and ``--help``, ``--version``); 2 bad input, reported in one ``error:`` line;
        1 internal failure; 130 interrupted.
    """
    app = build_app()
    try:
        # Not standalone: usage errors reach this function, which reports them in one line.
        status = app(args=argv, prog_name="scanrig", standalone_mode=False)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except typer.TyperException as exc:
        # Typer's usage errors (unknown option, missing argument, bad value); with no arguments
        # at all the "error" is the help, already printed (typer itself tells it by name).
        if type(exc).__name__ != "NoArgsIsHelpError":
            typer.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
            ctx = getattr(exc, "ctx", None)
            if ctx is not None:
                typer.echo(f"try '{ctx.command_path} --help'", err=True)
        return 2
    except InputError as exc:
        typer.echo(f"error: {exc}", err=True)
        return 2
    except (KeyboardInterrupt, typer.Abort):
        status = INTERRUPTED
    except ScanrigError as exc:
        typer.echo(f"error: {exc}", err=True)
        return 1
    except Exception:  # noqa: BLE001 - the last line of defence turns a crash into exit 1
        traceback.print_exc()
        typer.echo(f"internal error: {ISSUES_HINT}", err=True)
        return 1
    # Typer turns Ctrl-C inside a verb into ``Exit(130)``, which it returns here; no verb exits 130 itself.
    if status == INTERRUPTED:
        typer.echo("interrupted", err=True)
    return status if isinstance(status, int) else 0


def run(argv: list[str] | None = None) -> NoReturn:
    """Console-script entry point: run :func:`main` and end the process with its status.

    Python's exit handlers run and the standard streams are flushed, as at a normal exit; the
    interpreter's own teardown is skipped. In it, Arrow's native thread pools (Parquet) can abort a
    process whose work is done ("terminate called without an active exception", exit 134;
    apache/arrow#34314), which a script would read as a failed scan. Every file scanrig writes is
    closed before ``main`` returns, so nothing is lost.
    """
    status = main(argv)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: nothing more can reach it
            pass
    os._exit(status)

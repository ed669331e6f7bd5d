"""The ``scanrig`` command: one thin subcommand per pipeline stage (see :mod:`scanrig.cli.main`)."""

"""Child process of the detect kill/resume test: ``python -m tests.reliability.detect_child ROOT``.

Runs ``scanrig detect ROOT --resume`` through the command line, with a checkpoint of
``traces.parquet`` after every chunk of frames (instead of every 30 s) so that a kill at a random
moment can land before, between or inside checkpoint writes. With ``SCANRIG_TEST_HOLD=1`` in
the environment, the second chunk waits (up to 60 s) before it runs, so that a signal sent after
the first checkpoint lands mid-run on any machine. SIGINT gets Python's default handler, as
under an interactive shell: a process started in the background by a non-interactive shell
(``cmd &``, as a CI script may run pytest) inherits SIGINT ignored, and Python then installs no
KeyboardInterrupt handler, so Ctrl-C did nothing and the detection ran to the end (exit 0).
"""

import functools
import os
import signal
import sys
import time

from scanrig.cli.main import run
from scanrig.laser import session_detect

if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)
    session_detect.detect_session = functools.partial(session_detect.detect_session, checkpoint_s=0.0)
    if os.environ.get("SCANRIG_TEST_HOLD") == "1":
        run_job, started = session_detect._run_job, []

        def held_job(job):
            if len(started) == 1:
                time.sleep(60.0)  # interrupted by the test's signal
            started.append(job)
            return run_job(job)

        session_detect._run_job = held_job
    run(["detect", sys.argv[1], "--mode", "spot", "--resume"])

"""Child process of the detect kill/resume test: ``python -m tests.reliability.detect_child ROOT``.

Runs ``scanrig detect ROOT --resume`` through the command line, with a checkpoint of
``traces.parquet`` after every chunk of frames (instead of every 30 s) so that a kill at a random
moment can land before, between or inside checkpoint writes. With ``SCANRIG_TEST_HOLD=1`` in
the environment, every chunk after the first waits (up to 60 s) before it runs, so that a signal
sent after the first checkpoint always lands mid-run: the Ctrl-C test on a loaded machine found
the 128 small frames already done when its signal arrived (exit 0).
"""

import functools
import os
import sys
import time

from scanrig.cli.main import main
from scanrig.laser import session_detect

if __name__ == "__main__":
    session_detect.detect_session = functools.partial(session_detect.detect_session, checkpoint_s=0.0)
    if os.environ.get("SCANRIG_TEST_HOLD") == "1":
        run_job, started = session_detect._run_job, []

        def held_job(job):
            if started:
                time.sleep(60.0)  # interrupted by the test's signal
            started.append(job)
            return run_job(job)

        session_detect._run_job = held_job
    sys.exit(main(["detect", sys.argv[1], "--mode", "spot", "--resume"]))

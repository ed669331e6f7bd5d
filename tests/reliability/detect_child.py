"""Child process of the detect kill/resume test: ``python -m tests.reliability.detect_child ROOT``.

Runs ``scanrig detect ROOT --resume`` through the command line, with a checkpoint of
``traces.parquet`` after every chunk of frames (instead of every 30 s) so that a kill at a random
moment can land before, between or inside checkpoint writes. Each chunk is slowed by 50 ms so
that a signal sent after the first checkpoint lands mid-run on any machine (the 128 small frames
took ~0.3 s, and a Ctrl-C test on a fast run found the detection already finished, exit 0).
"""

import functools
import sys
import time

from scanrig.cli.main import main
from scanrig.laser import session_detect

if __name__ == "__main__":
    session_detect.detect_session = functools.partial(session_detect.detect_session, checkpoint_s=0.0)
    run_job = session_detect._run_job

    def slow_job(job):
        time.sleep(0.05)
        return run_job(job)

    session_detect._run_job = slow_job
    sys.exit(main(["detect", sys.argv[1], "--mode", "spot", "--resume"]))

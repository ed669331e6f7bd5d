"""Child process of the detect kill/resume test: ``python -m tests.reliability.detect_child ROOT``.

Runs ``scanrig detect ROOT --resume`` through the command line, with a checkpoint of
``traces.parquet`` after every chunk of frames (instead of every 30 s) so that a kill at a random
moment can land before, between or inside checkpoint writes.
"""

import functools
import sys

from scanrig.cli.main import main
from scanrig.laser import session_detect

if __name__ == "__main__":
    session_detect.detect_session = functools.partial(session_detect.detect_session, checkpoint_s=0.0)
    sys.exit(main(["detect", sys.argv[1], "--mode", "spot", "--resume"]))

"""Child process of the kill/resume test: ``python -m tests.scan.scan_child ROOT [--resume]``.

Runs the stand-in scan of ``test_loop`` (slowed down so that a kill lands mid-scan) and writes
the final points to ``ROOT/points.npy``.
"""

import sys
from pathlib import Path

import numpy as np

from tests.scan import fakerig
from tests.scan.test_loop import _scan, _xyz

#: Seconds per move: slow enough that a kill can land anywhere in a frame's writes.
MOVE_DELAY_S = 0.02

if __name__ == "__main__":
    root = Path(sys.argv[1])
    result = _scan(root, fakerig.FakeRig(seed=1, delay_s=MOVE_DELAY_S), resume="--resume" in sys.argv)
    np.save(root / "points.npy", _xyz(result))

"""A rig that replays a recorded session folder: frames in order, beams checked against the record.

Replaying a scan with the same planner settings and seed commands exactly the recorded beams, so
the replay rig doubles as a determinism check; ``strict=False`` replays the frames whatever is
commanded (to re-run processing or another planner on old data).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.io.session import Session, read_image
from scanrig.scan.protocol import Beam, RigError
from scanrig.scan.store import read_state


class ReplayRig:
    """Cameras and positioner over a recorded session; implements both protocols.

    Parameters
    ----------
    root : str or Path
        A session folder with ``scan/<camera>/<frame>.png``; its ``scan/manifest.jsonl`` (if any)
        provides the recorded beams.
    strict : bool
        Refuse a commanded beam that differs from the recorded one.
    """

    def __init__(self, root: str | Path, strict: bool = True):
        session = Session(root)
        self.names = session.camera_names("scan")
        self._frames = list(session.frames("scan", self.names).values())
        self._dark = {name: p for name in self.names if (p := session.dark_path(name)) is not None}
        manifest = Path(root) / "scan" / "manifest.jsonl"
        self._beams = read_state(root).beams if manifest.exists() and strict else []
        self.strict = strict
        self._next = 0
        self.laser = False

    def move_to(self, beam: Beam) -> None:
        """Advance to the next recorded frame (checking the beam in strict mode)."""
        index = self._next
        if index >= len(self._frames):
            raise RigError(f"replay: the recording holds {len(self._frames)} frames; frame {index} was asked for")
        if self.strict and index < len(self._beams) and beam != self._beams[index]:
            raise RigError(f"replay: the beam commanded for frame {index} differs from the recorded one "
                           f"(recorded {self._beams[index].as_row()[:6]}, commanded {beam.as_row()[:6]})")
        self._next += 1

    def set_laser(self, on: bool) -> None:
        self.laser = bool(on)

    def grab(self) -> dict[str, np.ndarray]:
        """The images of the current frame, or the recorded dark frames before the first move.

        A camera that did not record the frame is missing from the result.
        """
        if self._next == 0:
            if not self._dark:
                raise RigError("replay: grab before the first move, and the recording has no dark frame")
            paths = self._dark
        else:
            paths = self._frames[self._next - 1]
        return {name: read_image(paths[name]) for name in self.names if name in paths}

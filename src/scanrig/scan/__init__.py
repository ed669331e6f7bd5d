"""Scanning: the rig protocol, the adaptive planner, the resumable session store, distributed processing.

``run_scan`` (in :mod:`scanrig.scan.loop`) drives any rig that follows the protocol of
:mod:`scanrig.scan.protocol`; see ``docs/scanning.md``. This package never imports
``scanrig.sim``: the simulator's ``VirtualRig`` follows the protocol structurally.
"""

from scanrig.scan.protocol import Beam, Cameras, LaserPositioner, RigError

__all__ = ["Beam", "Cameras", "LaserPositioner", "RigError"]

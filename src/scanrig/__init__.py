"""scanrig: multi-camera laser triangulation, calibrated to the noise limit.

The public API is flat (``scanrig.load_rig``, ``scanrig.Camera``, ``scanrig.triangulate`` …);
names are resolved on first use so that ``import scanrig`` stays fast and optional
dependencies (PyTorch, OpenCV) load only when a stage needs them.
"""

from __future__ import annotations

import importlib
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("scanrig")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0+unknown"

#: Public name -> module that defines it.
_EXPORTS = {
    "Camera": "scanrig.geometry.camera",
    "Rig": "scanrig.geometry.rig",
    "RigidTransform": "scanrig.geometry.transform",
    "load_rig": "scanrig.io.rig_file",
    "save_rig": "scanrig.io.rig_file",
    "triangulate": "scanrig.geometry.triangulation",
    "detect_spots": "scanrig.laser.spots",
    "detect_stripe": "scanrig.laser.stripes",
    "to_open3d": "scanrig.exports",
    "ScanrigError": "scanrig.errors",
    "InputError": "scanrig.errors",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'scanrig' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return __all__

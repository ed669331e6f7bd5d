"""Rig design: where to put the cameras, and what accuracy a rig will reach before it is built.

``design_rig`` chooses camera poses and lenses in an allowed mounting region so that as much of
the object's surface as possible is seen by two or more cameras within an accuracy target;
``analyze_existing`` predicts coverage, uncertainty and sampling density of a given rig. See
``docs/rig-design.md``.
"""

from scanrig.design.analysis import RigAnalysis, analyze_rig
from scanrig.design.candidates import MountingError
from scanrig.design.elements import MeshError, SurfaceElements, surface_elements
from scanrig.design.plan import Design, TargetError, analyze_existing, design_rig
from scanrig.design.spec import DesignSpec, load_spec

__all__ = ["Design", "DesignSpec", "MeshError", "MountingError", "RigAnalysis", "SurfaceElements", "TargetError",
           "analyze_existing", "analyze_rig", "design_rig", "load_spec", "surface_elements"]

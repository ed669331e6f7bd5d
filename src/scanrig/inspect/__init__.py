"""Inspection against CAD: align a scan to the part's model and map the deviation of every point.

As GOM Inspect, PolyWorks or CloudCompare's cloud-to-mesh distance do: a global coarse alignment
(:mod:`~scanrig.inspect.coarse`), a robust point-to-plane ICP (:mod:`~scanrig.inspect.icp`), the
signed distance of every point to the CAD surface (:mod:`~scanrig.inspect.deviation`), the worst
out-of-tolerance regions (:mod:`~scanrig.inspect.regions`), and the files (:mod:`~scanrig.inspect.outputs`).

Layer: beside :mod:`scanrig.surface`; imports geometry and io only (never sim, never report).

Example::

    from scanrig.inspect import inspect_cloud, load_cad, write_inspection
    cad = load_cad("part.stl", units="mm")
    inspection = inspect_cloud(points_m, cad, tolerance_m=1e-4, seed=0)
    write_inspection(inspection, Path("out"), points_m=points_m, title="part 17")
"""

from scanrig.inspect.cad import load_cad
from scanrig.inspect.inspection import AlignmentError, Inspection, inspect_cloud
from scanrig.inspect.outputs import write_inspection

__all__ = ["AlignmentError", "Inspection", "inspect_cloud", "load_cad", "write_inspection"]

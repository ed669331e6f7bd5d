"""Robust neural surface filter (Chen & Jain robust back-propagation with a bootstrap).

``filter_points`` splits a cloud into height-field charts, fits each with a small network on
Hampel's tanh loss (local trimmed start, held-out residual scale, bootstrap upper bound,
reweighting step), and returns per-point inlier flags, robust scores, residuals and denoised
positions. See ``docs/surface-filter.md``. Importing this package imports PyTorch (the ``nn``
extra).
"""

from scanrig.surface.filter import FilterResult, filter_points
from scanrig.surface.hampel import HampelConstants
from scanrig.surface.meshing import mesh_from_result
from scanrig.surface.fit_settings import FitSettings
from scanrig.surface.sampling_need import SamplingNeedMap, sampling_need

__all__ = ["FilterResult", "FitSettings", "HampelConstants", "SamplingNeedMap", "filter_points",
           "mesh_from_result", "sampling_need"]

"""Reports a person wants to look at: calibration evidence, detections, the cloud in 3-D, accuracy.

:func:`write_report` writes one self-contained ``report.html`` (no network needed to view it).
matplotlib is imported inside the plotting functions only.
"""

from scanrig.report.session_report import write_report

__all__ = ["write_report"]

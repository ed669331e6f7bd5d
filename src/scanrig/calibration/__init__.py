"""Calibration: target detection, initialisation, joint bundle adjustment, uncertainty, re-localisation.

>>> from scanrig.calibration import calibrate_session        # doctest: +SKIP
>>> result = calibrate_session("SESSION")                    # writes SESSION/rig.toml
"""

from scanrig.calibration.observations import Observations
from scanrig.calibration.pipeline import CalibrationResult, calibrate
from scanrig.calibration.session_calibration import calibrate_session

__all__ = ["CalibrationResult", "Observations", "calibrate", "calibrate_session"]

"""The source paper's camera parameterisation as a special case of OpenCV's model.

The source method (after Heikkilä & Silvén, its reference [9]) describes a camera by an effective
focal length ``f``, a horizontal scale factor ``s`` (pixel aspect), the principal point
``(Cx, Cy)``, one radial coefficient ``a`` and one decentering coefficient ``b``, on image-plane
coordinates ``(x1, x2) = (X/Z, Y/Z)``::

    x1d = x1 + a x1 r²  + 2 b x1 x2
    x2d = x2 + a x2 r²  + b (r² + 2 x2²)          r² = x1² + x2²
    u = s f x1d + Cx,   v = f x2d + Cy

(The paper's printed decentering formula is garbled in extraction; this is the Heikkilä–Silvén
decentering term that the paper cites, with its second coefficient fixed at zero.) In OpenCV's
terms that is model ``opencv4`` with::

    fx = s f,  fy = f,  cx = Cx,  cy = Cy,  k1 = a,  k2 = 0,  p1 = b,  p2 = 0

so a camera in the paper's form converts exactly, and an OpenCV camera converts back only when
``k2 = p2 = 0`` (and higher coefficients vanish).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scanrig.errors import InputError
from scanrig.geometry.camera import Camera
from scanrig.geometry.distortion import pad_coefficients
from scanrig.geometry.transform import RigidTransform


@dataclass(frozen=True)
class SourcePaperIntrinsics:
    """The source paper's intrinsics.

    Parameters
    ----------
    f : float
        Effective focal length, pixels (vertical).
    s : float
        Scale factor: horizontal over vertical pixel density (``fx / fy``).
    cx, cy : float
        Principal point, pixels.
    a : float
        Radial distortion coefficient (OpenCV's k1).
    b : float
        Decentering coefficient (OpenCV's p1).
    """

    f: float
    s: float
    cx: float
    cy: float
    a: float = 0.0
    b: float = 0.0

    def to_camera(self, name: str, width: int, height: int,
                  cam_from_world: RigidTransform | None = None) -> Camera:
        """The equivalent ``opencv4`` :class:`Camera`."""
        params = np.array([self.s * self.f, self.f, self.cx, self.cy, self.a, 0.0, self.b, 0.0])
        return Camera(name, "opencv4", params, width, height, cam_from_world or RigidTransform.identity())

    @classmethod
    def from_camera(cls, camera: Camera) -> SourcePaperIntrinsics:
        """Convert back; raises :class:`InputError` when the camera uses terms the paper lacks."""
        d = pad_coefficients(camera.params[4:])
        extra = {name: float(d[i]) for i, name in ((1, "k2"), (3, "p2")) if d[i] != 0.0}
        extra.update({f"coefficient {i + 1}": float(d[i]) for i in range(4, 12) if d[i] != 0.0})
        if extra:
            raise InputError(
                f"camera {camera.name!r} has distortion terms the source paper's model lacks: {extra}"
            )
        fx, fy, cx, cy = camera.params[:4]
        return cls(f=fy, s=fx / fy, cx=cx, cy=cy, a=d[0], b=d[2])

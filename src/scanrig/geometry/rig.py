"""An ordered set of cameras sharing one world frame."""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping

from scanrig.errors import InputError
from scanrig.geometry.camera import Camera


class Rig(Mapping[str, Camera]):
    """Ordered, immutable mapping ``name -> Camera``; the order is the order given.

    Parameters
    ----------
    cameras : iterable of Camera
        Cameras in rig order; names must be unique.
    """

    def __init__(self, cameras: Iterable[Camera]):
        cams = list(cameras)
        for cam in cams:
            if not isinstance(cam, Camera):
                raise InputError(f"Rig takes Camera objects, got {type(cam).__name__}")
        names = [cam.name for cam in cams]
        duplicates = sorted({n for n in names if names.count(n) > 1})
        if duplicates:
            raise InputError(f"camera names must be unique in a rig, duplicated: {duplicates}")
        self._cameras = {cam.name: cam for cam in cams}

    def __getitem__(self, name: str) -> Camera:
        try:
            return self._cameras[name]
        except KeyError:
            raise KeyError(f"no camera {name!r} in rig; cameras are {list(self._cameras)}") from None

    def __iter__(self) -> Iterator[str]:
        return iter(self._cameras)

    def __len__(self) -> int:
        return len(self._cameras)

    @property
    def names(self) -> list[str]:
        """Camera names in rig order."""
        return list(self._cameras)

    @property
    def cameras(self) -> list[Camera]:
        """Cameras in rig order."""
        return list(self._cameras.values())

    def replace_camera(self, camera: Camera) -> "Rig":
        """A new rig with the camera of the same name replaced (order kept)."""
        if camera.name not in self._cameras:
            raise InputError(f"no camera {camera.name!r} in rig; cameras are {self.names}")
        return Rig(camera if c.name == camera.name else c for c in self.cameras)

    def __repr__(self) -> str:
        return f"Rig({self.names})"

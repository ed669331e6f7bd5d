"""Rigid transforms, camera models, rays and triangulation (numpy and scipy only)."""

from scanrig.geometry.camera import Camera
from scanrig.geometry.rig import Rig
from scanrig.geometry.transform import RigidTransform

__all__ = ["Camera", "Rig", "RigidTransform"]

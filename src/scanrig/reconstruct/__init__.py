"""Reconstruction: cross-camera correspondence, reflection rejection, stripes and light planes,
points with per-point quality (``points.ply``), evaluation against a true surface, and the
passive-stereo baseline. See ``docs/reconstruction.md``."""

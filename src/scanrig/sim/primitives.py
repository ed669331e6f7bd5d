"""Procedural objects as triangle meshes, in their own frame (metres, z up).

Flat faces are exact. Curved surfaces are tessellated finely enough that the chord sag stays
below :data:`MAX_SAG_M`; the ground truth is always the tessellated mesh itself (the same
triangles the renderer intersects), so truth and images agree exactly.
"""

from __future__ import annotations

import numpy as np
import trimesh

from scanrig.errors import InputError

#: Largest distance between a tessellated curved surface and the ideal one, metres.
MAX_SAG_M = 5e-6


def _sections(radius_m: float) -> int:
    """Segments of a circle of this radius so that the chord sag is below MAX_SAG_M."""
    # sag = r (1 - cos(pi / n)) ~ r pi² / (2 n²)
    return int(np.clip(np.ceil(np.pi * np.sqrt(radius_m / (2 * MAX_SAG_M))), 32, 2048))


def plane(size_m) -> trimesh.Trimesh:
    """A rectangle ``(width, depth)`` centred on the origin in the z = 0 plane, normal +z."""
    w, d = _positive(size_m, 2, "plane size_m")
    v = np.array([[-w / 2, -d / 2, 0], [w / 2, -d / 2, 0], [w / 2, d / 2, 0], [-w / 2, d / 2, 0]])
    return trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3]], process=False)


def box(size_m) -> trimesh.Trimesh:
    """An axis-aligned box of extents ``(x, y, z)`` centred on the origin."""
    return trimesh.creation.box(extents=_positive(size_m, 3, "box size_m"))


def sphere(radius_m: float) -> trimesh.Trimesh:
    """A sphere centred on the origin (icosphere, subdivided until the sag is below MAX_SAG_M)."""
    (r,) = _positive([radius_m], 1, "sphere radius_m")
    # icosphere edge ~ 1.1 r / 2**k; sag ~ edge² / (8 r)
    k = int(np.clip(np.ceil(np.log2(1.1 * np.sqrt(r / (8 * MAX_SAG_M)))), 2, 7))
    return trimesh.creation.icosphere(subdivisions=k, radius=r)


def cylinder(radius_m: float, height_m: float) -> trimesh.Trimesh:
    """A closed cylinder of axis z centred on the origin."""
    r, h = _positive([radius_m, height_m], 2, "cylinder radius_m, height_m")
    return trimesh.creation.cylinder(radius=r, height=h, sections=_sections(r))


def torus(major_radius_m: float, minor_radius_m: float) -> trimesh.Trimesh:
    """A torus around the z axis centred on the origin."""
    R, r = _positive([major_radius_m, minor_radius_m], 2, "torus radii")
    if r >= R:
        raise InputError(f"torus minor_radius_m must be smaller than major_radius_m, got {r} >= {R}")
    return trimesh.creation.torus(R, r, major_sections=_sections(R + r), minor_sections=_sections(r) // 2)


def stepped_block(size_m, n_steps: int = 3) -> trimesh.Trimesh:
    """A staircase block with sharp edges: ``n_steps`` steps rising along +x, base on z = 0.

    Parameters
    ----------
    size_m : (3,) float
        Overall length (x), width (y) and height (z), metres.
    n_steps : int
        Number of steps; step i spans ``x in [i, i+1] * length / n`` with height ``(i+1) * height / n``.
    """
    length, width, height = _positive(size_m, 3, "stepped_block size_m")
    if n_steps < 1:
        raise InputError(f"stepped_block n_steps must be >= 1, got {n_steps}")
    parts = []
    for i in range(n_steps):
        h = height * (i + 1) / n_steps
        x0 = -length / 2 + i * length / n_steps
        bounds = [[x0, -width / 2, 0.0], [x0 + length / n_steps, width / 2, h]]
        parts.append(trimesh.creation.box(bounds=bounds))
    return trimesh.util.concatenate(parts)


def ibeam_joint(length_m: float = 0.4, depth_m: float = 0.12, flange_m: float = 0.08,
                thickness_m: float = 0.008, weld_m: float = 0.006) -> trimesh.Trimesh:
    """Two welded steel I-beams: a horizontal beam along x, a post standing on it, fillet welds.

    Parameters
    ----------
    length_m : float
        Length of the horizontal beam and height of the post, metres.
    depth_m, flange_m, thickness_m : float
        I-section depth (flange to flange), flange width and plate thickness, metres.
    weld_m : float
        Leg of the fillet welds (modelled as cylinders of this radius along the joint lines).
    """
    L, d, b, t, w = _positive([length_m, depth_m, flange_m, thickness_m, weld_m], 5, "ibeam_joint sizes")
    beam = _i_section(L, d, b, t)                                 # along x, web vertical, base z = 0
    post = _i_section(L, d, b, t)
    post.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    post.apply_translation([0.0, 0.0, d + L / 2])                 # along z, standing on the beam
    welds = []
    for y in (-t / 2, t / 2):                                     # along both sides of the post's web
        weld = trimesh.creation.cylinder(radius=w, height=d - 2 * t, sections=_sections(w))
        weld.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
        weld.apply_translation([0.0, y, d])
        welds.append(weld)
    return trimesh.util.concatenate([beam, post, *welds])


def _i_section(length, depth, flange, t) -> trimesh.Trimesh:
    """An I-beam along x: two flanges of width ``flange`` and a web, base on z = 0."""
    boxes = [
        [[-length / 2, -flange / 2, 0.0], [length / 2, flange / 2, t]],
        [[-length / 2, -flange / 2, depth - t], [length / 2, flange / 2, depth]],
        [[-length / 2, -t / 2, t], [length / 2, t / 2, depth - t]],
    ]
    return trimesh.util.concatenate([trimesh.creation.box(bounds=b) for b in boxes])


def freeform(size_m, amplitude_m: float = 0.03, n_grid: int = 200, seed: int = 0) -> trimesh.Trimesh:
    """A smooth free-form sheet ``z = f(x, y)`` (a sum of Gaussian bumps) with side skirts to z = 0.

    Parameters
    ----------
    size_m : (2,) float
        Extent in x and y, metres.
    amplitude_m : float
        Largest bump height, metres (the sheet sits at ``z = amplitude_m`` plus the bumps).
    n_grid : int
        Grid vertices per side.
    seed : int
        Seed of the bump layout (part of the scene).
    """
    sx, sy = _positive(size_m, 2, "freeform size_m")
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.linspace(-sx / 2, sx / 2, n_grid), np.linspace(-sy / 2, sy / 2, n_grid))
    centres = rng.uniform(-0.4, 0.4, size=(6, 2)) * [sx, sy]
    widths = rng.uniform(0.12, 0.3, size=6) * min(sx, sy)
    heights = rng.uniform(-1.0, 1.0, size=6) * amplitude_m
    z = amplitude_m + sum(h * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2) / (2 * s * s))
                          for c, s, h in zip(centres, widths, heights))
    z = np.maximum(z, 0.1 * amplitude_m)
    verts = np.column_stack([x.ravel(), y.ravel(), z.ravel()])
    idx = np.arange(n_grid * n_grid).reshape(n_grid, n_grid)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = [np.column_stack([a, b, c]), np.column_stack([a, c, d])]
    # skirts: the boundary loop dropped to z = 0
    loop = np.concatenate([idx[0, :], idx[1:, -1], idx[-1, -2::-1], idx[-2:0:-1, 0]])
    base = verts[loop] * [1, 1, 0]
    n0 = len(verts)
    verts = np.vstack([verts, base])
    top, bottom = loop, n0 + np.arange(len(loop))
    top_next, bottom_next = np.roll(top, -1), np.roll(bottom, -1)
    faces += [np.column_stack([top_next, top, bottom]), np.column_stack([top_next, bottom, bottom_next])]
    mesh = trimesh.Trimesh(verts, np.vstack(faces), process=False)
    mesh.fix_normals()
    return mesh


def _positive(values, n: int, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64).ravel()
    if arr.size != n or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
        raise InputError(f"{name} must be {n} positive number(s), got {values!r}")
    return arr


#: Shape name in scene files -> builder.
SHAPES = {
    "plane": plane,
    "box": box,
    "sphere": sphere,
    "cylinder": cylinder,
    "torus": torus,
    "stepped_block": stepped_block,
    "ibeam_joint": ibeam_joint,
    "freeform": freeform,
}

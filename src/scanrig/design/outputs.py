"""Files a design writes: the rig, maps on the mesh, views, and the tables.

``OUT/rig.toml``          the designed rig (``scanrig.load_rig``; ``simulate_session(..., rig=)`` renders it)
``OUT/coverage.ply``      the mesh with per-vertex predictions (fields below)
``OUT/coverage.png``      views of the views-count and predicted-sigma maps, cameras marked
``OUT/cameras.csv``       one row per camera (pose, lens, seen area, marginal gain)
``OUT/design.toml``       the spec used, the headline figures and the ring comparison

PLY vertex fields (a vertex takes the worst value of the faces around it, so that a gap in
coverage is never hidden by a neighbour): ``x y z`` (float64, m, world), ``n_views`` (uint8),
``sigma`` (float64, m, predicted largest-axis 1-sigma; NaN where not triangulable),
``speckle_floor`` (float64, m), ``triangulation_angle_deg`` (float32), ``density_per_mm2``
(float32), ``covered`` (uint8, 1 = within target).
"""

from __future__ import annotations

import csv
import io
from dataclasses import asdict
from pathlib import Path

import numpy as np
import tomli_w

from scanrig.io.atomic import atomic_write, write_text_atomic
from scanrig.io.rig_file import save_rig

from .analysis import RigAnalysis
from .candidates import look_at_pose, make_camera, up_basis
from .plan import Design
from .spec import CameraSpec
from .visibility import RayCaster


def write_design(out_dir: str | Path, design: Design, provenance: dict) -> list[Path]:
    """Write every output of a design into ``out_dir`` (created if needed).

    Parameters
    ----------
    out_dir : str or Path
    design : Design
    provenance : dict
        Command line, seed, mesh name, version: recorded in every file.

    Returns
    -------
    list of Path
        The files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    comments = [f"{k}: {v}" for k, v in provenance.items()]
    summary = design_summary(design)
    metadata = {**{k: str(v) for k, v in provenance.items()},
                "covered_fraction": summary["covered_fraction"], "target_sigma_m": design.spec.target.sigma_m}
    paths = [out / "rig.toml", out / "coverage.ply", out / "coverage.png", out / "cameras.csv", out / "design.toml"]
    save_rig(design.rig, paths[0], metadata=metadata, comments=["designed by scanrig design", *comments])
    write_coverage_ply(paths[1], design.mesh, design.analysis, comments)
    write_views_png(paths[2], design)
    write_text_atomic(paths[3], camera_table_csv(design))
    doc = {"provenance": {k: str(v) for k, v in provenance.items()}, "summary": summary,
           "spec": _plain(asdict(design.spec))}
    write_text_atomic(paths[4], tomli_w.dumps(doc))
    return paths


def design_summary(design: Design) -> dict:
    """Headline figures: covered fraction, views, sigma percentiles, ring comparison, gains."""
    a = design.analysis
    finite = np.isfinite(a.sigma_m)
    summary = {
        "n_cameras": len(design.rig),
        "target_sigma_m": design.spec.target.sigma_m,
        "covered_fraction": a.covered_fraction,
        "seen_by_min_views_fraction": a.fraction(a.n_views >= design.spec.target.min_views),
        "seen_by_one_fraction": a.fraction(a.n_views >= 1),
        "sigma_median_m": float(np.median(a.sigma_m[finite])) if finite.any() else float("nan"),
        "sigma_p95_m": float(np.percentile(a.sigma_m[finite], 95)) if finite.any() else float("nan"),
        "speckle_floor_median_m": float(np.median(a.speckle_floor_m[finite])) if finite.any() else float("nan"),
    }
    if design.ring is not None:
        summary["ring_covered_fraction"] = design.ring.covered_fraction
    if design.selection is not None:
        summary["marginal_gain"] = [float(s.gain) for s in design.selection.steps]
        summary["refinement_exchanges"] = design.selection.refinement_exchanges
        summary["reachable_fraction"] = design.selection.reachable_fraction
    return summary


def camera_rows(design: Design) -> list[dict]:
    """One row per camera: pose, lens, seen area, focus, gains (the table the CLI prints)."""
    a = design.analysis
    look_at = np.asarray(design.spec.mounting.look_at)
    steps = design.selection.steps if design.selection is not None else [None] * len(design.rig)
    rows = []
    for i, (cam, step) in enumerate(zip(design.rig.cameras, steps, strict=True)):
        center = cam.center_world
        rows.append({
            "camera": cam.name,
            "focal_length_mm": 1e3 * cam.params[0] * design.spec.camera.pixel_pitch_m,
            "x_m": center[0], "y_m": center[1], "z_m": center[2],
            "distance_m": float(np.linalg.norm(center - look_at)),
            "seen_fraction": a.fraction(a.used[i]),
            "in_focus_fraction": float(a.in_focus_fraction[i]),
            "covered_after": step.covered_fraction if step else float("nan"),
            "marginal_gain": step.gain if step else float("nan"),
            "loss_if_removed": step.loss_if_removed if step else float("nan"),
        })
    return rows


def camera_table_csv(design: Design) -> str:
    """:func:`camera_rows` as CSV text (fractions of the surface area; metres; millimetres)."""
    rows = camera_rows(design)
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()} for r in rows)
    return buffer.getvalue()


def vertex_maps(mesh, analysis: RigAnalysis) -> dict[str, np.ndarray]:
    """Per-vertex fields of ``coverage.ply`` from per-face predictions (worst face around a vertex).

    ``analysis`` must be on the mesh's faces, one element per face in face order.
    """
    faces = np.asarray(mesh.faces)
    n_vertices = len(mesh.vertices)
    corner_vertex = faces.ravel()

    def worst(values, op, fill):
        out = np.full(n_vertices, fill, dtype=np.float64)
        op.at(out, corner_vertex, np.repeat(values, 3))
        return out

    sigma = worst(analysis.sigma_m, np.maximum, -np.inf)
    floor = worst(np.where(np.isfinite(analysis.speckle_floor_m), analysis.speckle_floor_m, np.inf), np.maximum,
                  -np.inf)
    return {
        "x": np.asarray(mesh.vertices[:, 0], np.float64),
        "y": np.asarray(mesh.vertices[:, 1], np.float64),
        "z": np.asarray(mesh.vertices[:, 2], np.float64),
        "n_views": worst(analysis.n_views, np.minimum, np.inf).astype(np.uint8),
        "sigma": np.where(np.isfinite(sigma), sigma, np.nan),
        "speckle_floor": np.where(np.isfinite(floor), floor, np.nan),
        "triangulation_angle_deg": np.degrees(worst(analysis.triangulation_angle_rad, np.minimum, np.inf)
                                              ).astype(np.float32),
        "density_per_mm2": (1e-6 * worst(analysis.density_per_m2, np.minimum, np.inf)).astype(np.float32),
        "covered": worst(analysis.covered.astype(np.float64), np.minimum, np.inf).astype(np.uint8),
    }


def write_coverage_ply(path: str | Path, mesh, analysis: RigAnalysis, comments=()) -> None:
    """The mesh with :func:`vertex_maps` fields, binary PLY (see the module docstring)."""
    from scanrig.io.ply import write_ply

    write_ply(path, vertex_maps(mesh, analysis), faces=np.asarray(mesh.faces),
              comments=["units m, world frame; predictions of scanrig design", *comments])


def write_views_png(path: str | Path, design: Design, size_px: int = 420) -> None:
    """Two views each of the views-count map and the predicted-sigma map, cameras marked.

    The views are ray-cast (one ray per pixel against the analysed mesh), shaded by the angle
    between the surface and the line of sight, so that they stay exact for any mesh size.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mesh, a = design.mesh, design.analysis
    caster = RayCaster(mesh)
    target_mm = 1e3 * design.spec.target.sigma_m
    n_cams = len(design.rig)
    views_cmap = plt.get_cmap("viridis", n_cams + 1)
    views_norm = matplotlib.colors.Normalize(-0.5, n_cams + 0.5)
    sigma_cmap = plt.get_cmap("magma_r").with_extremes(over="lightgrey")
    sigma_norm = matplotlib.colors.Normalize(0.0, target_mm)
    face_rgb = [views_cmap(views_norm(a.n_views))[:, :3],
                sigma_cmap(sigma_norm(np.where(np.isfinite(a.sigma_m), 1e3 * a.sigma_m, np.inf)))[:, :3]]
    titles = ["cameras seeing the surface", f"predicted sigma (mm); grey: above the target {target_mm:.3g} mm"]

    vertices = np.asarray(mesh.vertices)
    center = (vertices.min(axis=0) + vertices.max(axis=0)) / 2.0
    radius = float(np.linalg.norm(vertices - center, axis=1).max())
    up = np.asarray(design.spec.mounting.up, dtype=np.float64)
    fig, axes = plt.subplots(2, 2, figsize=(11, 10))
    for col, azimuth_deg in enumerate((-60.0, 120.0)):
        eye = center + 3.5 * radius * _direction(azimuth_deg, 30.0, up)
        viewer = make_camera("view", CameraSpec(width_px=size_px, height_px=size_px, pixel_pitch_m=1.0),
                             size_px * 1.3, look_at_pose(eye, center, up))
        u, v = np.meshgrid(np.arange(size_px), np.arange(size_px))
        origins, dirs = viewer.rays(np.c_[u.ravel(), v.ravel()].astype(np.float64))
        _, face = caster.first_hit(origins, dirs)
        hit = face >= 0
        shade = np.ones(face.size)
        shade[hit] = 0.35 + 0.65 * np.abs(np.einsum("ij,ij->i", mesh.face_normals[face[hit]], dirs[hit]))
        q_cams = viewer.project(np.array([c.center_world for c in design.rig.cameras]))
        for row in range(2):
            image = np.ones((face.size, 3))
            image[hit] = face_rgb[row][face[hit]] * shade[hit, None]
            ax = axes[row, col]
            ax.imshow(image.reshape(size_px, size_px, 3))
            for cam, q in zip(design.rig.cameras, q_cams, strict=True):
                if np.all(np.isfinite(q)):
                    ax.plot(*q, marker="^", color="red", ms=8)
                    ax.annotate(cam.name, q, textcoords="offset points", xytext=(4, 4), fontsize=8, color="red")
            ax.set(xlim=(0, size_px - 1), ylim=(size_px - 1, 0), xticks=[], yticks=[],
                   title=titles[row] if col == 0 else f"view from azimuth {azimuth_deg:g}°")
    fig.colorbar(matplotlib.cm.ScalarMappable(views_norm, views_cmap), ax=axes[0].tolist(), label="cameras",
                 ticks=range(n_cams + 1), shrink=0.8)
    fig.colorbar(matplotlib.cm.ScalarMappable(sigma_norm, sigma_cmap), ax=axes[1].tolist(), label="sigma (mm)",
                 extend="max", shrink=0.8)
    with atomic_write(path, "wb") as f:
        fig.savefig(f, format="png", dpi=90)
    plt.close(fig)


def _direction(azimuth_deg: float, elevation_deg: float, up: np.ndarray) -> np.ndarray:
    """Unit vector at an azimuth (from the first horizontal axis) and elevation above the plane normal to ``up``."""
    up, e1, e2 = up_basis(up)
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.cos(el) * (np.cos(az) * e1 + np.sin(az) * e2) + np.sin(el) * up


def _plain(value):
    """Dataclass dicts to TOML-able values (tuples to lists, paths to strings, None dropped)."""
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items() if v is not None}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value

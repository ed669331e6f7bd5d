"""Rendering one camera's view: the laser-free background once, then small laser windows.

Image formation, in order (all linear until the sensor):

1. radiance of every pixel from rays through its centre; pixels that differ from a neighbour
   (object boundary, shadow or texture edge: :data:`EDGE_CONTRAST`) are re-rendered as the mean
   of ``s × s`` sub-pixel rays (pixel integration where it matters), met in closed form where the
   pixel lies on one flat, matte, evenly lit plane (:mod:`scanrig.sim.flat_edges`);
2. electrons = radiance × :attr:`Sensor.e_per_radiance`, then the Gaussian lens PSF;
3. a laser frame adds the laser's electrons only in a window around the projected footprints:
   in the window's pixels that the laser may light (one ray through each centre decides,
   :mod:`scanrig.sim.lit_pixels`) ``s × s`` sub-pixel rays per pixel are cast through the real
   distorted camera (occlusion and distortion exact), the optical image at s× resolution gets
   speckle and the PSF, and each pixel averages its block (pixel integration after blur, as on a
   real sensor);
4. noise, full well, gain, black level, rounding and clipping (:mod:`scanrig.sim.sensor`).

A colour camera (``scene.colour``, :mod:`scanrig.sim.colour`) sees the grey background times
``ambient_rgb`` per channel and the laser window, grown by the reach of the sub-surface halo,
through its channel responses; the whole frame is then demosaiced, white-balanced and, as stored,
JPEG-coded.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from scanrig.geometry import Camera
from scanrig.sim.colour import (
    ColourNoise,
    channel_electrons,
    colour_frame,
    expose_rgb,
    processed,
    stored,
)
from scanrig.sim.flat_edges import NORMAL_TOL, FlatHits, planar_pixels, plane_points
from scanrig.sim.laser import SURFACE_EPS_M, LaserTrace, reflect
from scanrig.sim.lit_pixels import lit_pixels
from scanrig.sim.materials import specular_lobe
from scanrig.sim.pixel_integration import edge_sample_offsets, integrate_pixels
from scanrig.sim.pixel_rays import PixelRayTable
from scanrig.sim.sensor import NoiseField, Sensor

#: Relative radiance step between neighbouring pixel centres that triggers supersampling.
EDGE_CONTRAST = 0.15
#: Radiance of rays that leave the scene, as a fraction of a white Lambertian under ambient light.
BACKDROP_ALBEDO = 0.1
#: Largest half-size of a laser window around one footprint point, pixels.
MAX_WINDOW_RADIUS_PX = 200
#: Lamp shadow rays are cast this far, metres (beyond any scene).
_FAR_M = 1e3
#: Camera rays shaded per block (scratch arrays stay in the CPU cache).
_BLOCK = 1 << 15


@dataclass(frozen=True)
class Window:
    """Laser electrons in a rectangle of the image: rows ``v0:v0+h``, columns ``u0:u0+w``."""

    v0: int
    u0: int
    electrons: np.ndarray   # (h, w) float32, after the PSF

    @property
    def slices(self):
        h, w = self.electrons.shape
        return slice(self.v0, self.v0 + h), slice(self.u0, self.u0 + w)

    def padded(self, pad: int, shape) -> Window:
        """The window grown by ``pad`` pixels on every side (no electrons there), cut to an image of
        ``shape`` (H, W)."""
        if pad == 0:
            return self
        h, w = self.electrons.shape
        v0, u0 = max(0, self.v0 - pad), max(0, self.u0 - pad)
        v1, u1 = min(shape[0], self.v0 + h + pad), min(shape[1], self.u0 + w + pad)
        out = np.zeros((v1 - v0, u1 - u0), dtype=self.electrons.dtype)
        out[self.v0 - v0:self.v0 - v0 + h, self.u0 - u0:self.u0 - u0 + w] = self.electrons
        return Window(v0, u0, out)


class CameraView:
    """A camera looking at a scene.

    Parameters
    ----------
    camera : Camera
    scene : Scene
    sensor : Sensor, optional
        Defaults to the scene's sensor.
    rng : numpy.random.Generator, optional
        Draws the camera's noise bank; needed only for noisy frames (:meth:`frame`).
    ray_table : PixelRayTable, optional
        The camera's ray table, to share it between views of several scenes.
    """

    def __init__(self, camera: Camera, scene, sensor: Sensor | None = None, rng: np.random.Generator | None = None,
                 ray_table: PixelRayTable | None = None):
        self.camera = camera
        self.scene = scene
        self.sensor = sensor or scene.sensor
        self.colour = scene.colour
        self._rng = rng
        self.ray_table = ray_table or PixelRayTable(camera)

    # --- background ---------------------------------------------------------------------------
    @cached_property
    def background_e(self) -> np.ndarray:
        """Noise-free laser-free image in electrons, shape (H, W), float32 (after the PSF)."""
        cam, table = self.camera, self.ray_table
        xy = table.xy.reshape(-1, 2)
        flat = FlatHits.empty(len(xy))
        radiance, obj = self._radiance_blocks(len(xy), lambda a, b: table.to_world(xy[a:b]), flat=flat)
        radiance = radiance.reshape(cam.height, cam.width)
        obj = obj.reshape(cam.height, cam.width)
        s, sigma_px = self.sensor.supersampling, self.sensor.psf_sigma_px
        idx = np.flatnonzero(_edges(radiance, obj)) if s > 1 else np.zeros(0, dtype=np.int64)
        centres = np.column_stack([idx % cam.width, idx // cam.width]).astype(np.float64)
        offsets = edge_sample_offsets(centres, s)                  # (2, n, s²), made once
        sub = np.empty((idx.size, s * s))
        planar = planar_pixels(idx, obj, flat)
        # blocks of whole pixels (s² samples each)
        per = max(1, _BLOCK // (s * s))

        def sub_rays(pixels):
            return table.rays_uv((centres[pixels, 0, None] + offsets[0, pixels]).ravel(),
                                 (centres[pixels, 1, None] + offsets[1, pixels]).ravel())[1]

        cast = np.flatnonzero(~planar)
        sub[cast] = self._radiance_blocks(cast.size * s * s, lambda a, b: sub_rays(cast[a // (s * s):b // (s * s)]),
                                          block=per * s * s)[0].reshape(-1, s * s)
        shading, on_plane = _BackgroundShading(self.scene), np.flatnonzero(planar)
        for a in range(0, on_plane.size, per):
            pixels = on_plane[a:a + per]
            centre = idx[pixels]
            points = plane_points(table.origin, sub_rays(pixels).reshape(pixels.size, s * s, 3),
                                  flat.normal[centre], flat.offset_m[centre]).reshape(-1, 3)
            sub[pixels] = shading.matte(np.repeat(obj.ravel()[centre], s * s), points,
                                        np.repeat(flat.lamp_W_m2[centre], s * s)).reshape(-1, s * s)
        e_per_radiance = self.sensor.e_per_radiance
        if sigma_px == 0:
            radiance.ravel()[idx] = sub.mean(axis=1)
            return (radiance * e_per_radiance).astype(np.float32)
        # The PSF acts on the optical image before the pixels integrate it (pixel_integration).
        return integrate_pixels(radiance * e_per_radiance, idx, offsets, sub.ravel() * e_per_radiance, s, sigma_px)

    @cached_property
    def noise(self) -> NoiseField | ColourNoise:
        """The camera's fast full-frame noise generator (needs ``rng`` at construction)."""
        if self._rng is None:
            raise ValueError("CameraView needs rng to draw noisy frames")
        if self.colour is not None:
            return ColourNoise(self.sensor, self.background_e, self.colour, self._rng)
        return NoiseField(self.sensor, self.background_e, self._rng)

    def _radiance_background(self, origin: np.ndarray, dirs: np.ndarray):
        """Laser-free radiance along camera rays from ``origin`` (3,), and the object hit (-1 on a miss)."""
        return self._radiance_blocks(len(dirs), lambda a, b: dirs[a:b], origin=origin)

    def _radiance_blocks(self, n: int, dirs_of, origin: np.ndarray | None = None, block: int | None = None,
                         flat: FlatHits | None = None):
        """:meth:`_radiance_background` of ``n`` camera rays whose directions ``dirs_of(a, b)`` gives
        for rays ``a:b``, block by block (every scratch array stays in the CPU cache); ``flat``
        (of ``n`` rays), when given, receives their flat hits."""
        origin = self.ray_table.origin if origin is None else np.asarray(origin, dtype=np.float64).reshape(3)
        block = block or _BLOCK
        radiance = np.empty(n)
        obj = np.empty(n, dtype=np.int64)
        shading = _BackgroundShading(self.scene)
        for a in range(0, n, block):
            b = min(n, a + block)
            radiance[a:b], obj[a:b] = shading.radiance(origin, dirs_of(a, b), flat, a)
        return radiance, obj

    def _surface(self, obj: np.ndarray, p: np.ndarray):
        """Albedo, specular fraction and roughness at hit points of objects ``obj``."""
        mats = self.scene.materials
        spec = np.array([m.specular for m in mats])[obj]
        rough = np.array([m.roughness_rad for m in mats])[obj]
        return _albedo(mats, obj, p), spec, rough

    # --- laser ----------------------------------------------------------------------------------
    def laser_window(self, trace: LaserTrace, rng: np.random.Generator | None = None) -> Window | None:
        """The laser's electrons around its footprints in this camera (None if none is in view).

        Parameters
        ----------
        trace : LaserTrace
        rng : numpy.random.Generator, optional
            Draws the speckle pattern when the sensor has ``speckle_contrast > 0``.
        """
        import cv2

        sensor = self.sensor
        found = self.window_mask(trace)
        if found is None:
            return None
        mask, u0, v0 = found
        rows, cols = np.nonzero(mask)
        lit = lit_pixels(self, mask, u0, v0, trace.sources)         # (pixels, sources)
        some = lit.any(axis=1)
        rows, cols, lit = rows[some], cols[some], lit[some]
        centres = np.column_stack([cols + u0, rows + v0]).astype(np.float64)
        s = sensor.supersampling
        radiance = self.laser_radiance(_subpixel_samples(centres, s), trace, np.repeat(lit, s * s, axis=0))
        # The image on the sensor at s× resolution: speckle and the lens PSF act on the optical
        # image, then each pixel integrates (averages) its s × s block.
        fine = np.zeros((mask.shape[0] * s, mask.shape[1] * s), dtype=np.float32)
        sub_r, sub_c = np.meshgrid(np.arange(s), np.arange(s), indexing="ij")
        fine[(rows[:, None] * s + sub_r.ravel()).ravel(), (cols[:, None] * s + sub_c.ravel()).ravel()] = radiance
        if sensor.speckle_contrast > 0 and rng is not None:
            fine *= _speckle(fine.shape, sensor.speckle_contrast, sensor.speckle_grain_px * s, rng)
        if sensor.psf_sigma_px > 0:
            fine = cv2.GaussianBlur(fine, (0, 0), sensor.psf_sigma_px * s, borderType=cv2.BORDER_CONSTANT)
        patch = _block_mean(fine, s) * sensor.e_per_radiance
        return Window(v0, u0, patch)

    def window_mask(self, trace: LaserTrace):
        """The pixels a laser trace's light may reach through the lens: discs around its
        footprints (their extent, the PSF's reach and two pixels), cut to the image.

        Returns
        -------
        (mask, u0, v0) or None
            ``mask`` (h, w) uint8, non-zero on the pixels, covering rows ``v0:v0+h`` and columns
            ``u0:u0+w``; None when no footprint is in view.
        """
        import cv2

        cam, sensor = self.camera, self.sensor
        if len(trace.footprint_points) == 0:
            return None
        p_cam = cam.cam_from_world.apply(trace.footprint_points)
        q = cam.project(trace.footprint_points)
        with np.errstate(invalid="ignore", divide="ignore"):
            r_px = trace.footprint_radius_m * cam.params[:2].max() / p_cam[:, 2]
        r_px = np.minimum(r_px + 3 * sensor.psf_sigma_px + 2, MAX_WINDOW_RADIUS_PX)
        ok = np.isfinite(q).all(axis=1) & (q[:, 0] + r_px >= 0) & (q[:, 1] + r_px >= 0)
        ok &= (q[:, 0] - r_px <= cam.width - 1) & (q[:, 1] - r_px <= cam.height - 1)
        if not np.any(ok):
            return None
        q, r_px = q[ok], r_px[ok]
        u0 = int(max(0, np.floor((q[:, 0] - r_px).min())))
        v0 = int(max(0, np.floor((q[:, 1] - r_px).min())))
        u1 = int(min(cam.width - 1, np.ceil((q[:, 0] + r_px).max())))
        v1 = int(min(cam.height - 1, np.ceil((q[:, 1] + r_px).max())))
        mask = np.zeros((v1 - v0 + 1, u1 - u0 + 1), dtype=np.uint8)
        for (uu, vv), rr in zip(np.rint(q - [u0, v0]).astype(int), np.ceil(r_px).astype(int)):
            cv2.circle(mask, (int(uu), int(vv)), int(rr), 1, thickness=-1)
        return mask, u0, v0

    def laser_radiance(self, q: np.ndarray, trace: LaserTrace, lit: np.ndarray | None = None) -> np.ndarray:
        """Radiance that the laser light adds at pixel positions ``q`` (N, 2), W/(m²·sr).

        ``lit`` (N, len(trace.sources)), bool, optional: where each source may light (elsewhere its
        light is taken as zero; :func:`~scanrig.sim.lit_pixels.lit_pixels`); default everywhere.
        """
        origin, dirs = self.ray_table.rays(q)
        caster = self.scene.raycaster
        ok, hits = caster.first_hits(origin, dirs)
        out = np.zeros(len(ok))
        for j, source in enumerate(trace.sources):
            at = np.arange(len(ok)) if lit is None else np.flatnonzero(lit[ok, j])
            if at.size == 0:
                continue
            # row gathers by np.take (half the time of fancy indexing)
            p, n, ng = (np.take(a, at, axis=0) for a in (hits.point, hits.shading_normal, hits.normal))
            inten, prop, path = source.evaluate(p)
            cos_i = np.maximum(-np.einsum("ij,ij->i", prop, n), 0.0) * (np.einsum("ij,ij->i", prop, ng) < 0)
            on = np.flatnonzero((inten > 0) & (cos_i > 0))
            if on.size == 0:
                continue
            start = np.take(ng, on, axis=0)             # shadow-ray origins p + ε ng
            start *= SURFACE_EPS_M
            start += np.take(p, on, axis=0)
            toward = np.take(prop, on, axis=0)
            np.negative(toward, out=toward)
            shadow = caster.occluded(start, toward, path[on] - 2 * SURFACE_EPS_M)
            on = on[~shadow]
            e = inten[on] * cos_i[on]
            # the surface only where this source's light lands
            albedo, spec, rough = self._surface(hits.obj[at[on]], p[on])
            brdf = albedo / np.pi
            shiny = np.flatnonzero(spec > 0)
            if shiny.size:
                sl = on[shiny]
                cos_a = np.einsum("ij,ij->i", reflect(prop[sl], n[sl]), -dirs[ok[at[sl]]])
                brdf[shiny] += spec[shiny] * specular_lobe(cos_a, rough[shiny])
            out[at[on]] += e * brdf
        radiance = np.zeros(len(q))
        radiance[ok] = out
        return radiance

    # --- frames -----------------------------------------------------------------------------------
    def clean_frame_e(self, trace: LaserTrace | None = None) -> np.ndarray:
        """Noise-free expected electrons of a frame, shape (H, W), float32."""
        img = self.background_e.copy()
        win = self.laser_window(trace) if trace is not None else None
        if win is not None:
            img[win.slices] += win.electrons
        return img

    def clean_frame(self, trace: LaserTrace | None = None) -> np.ndarray:
        """Noise-free digital frame as stored: (H, W) grey, or (H, W, 3) RGB for a colour camera."""
        if self.colour is None:
            return self.sensor.expose_clean(self.clean_frame_e(trace))
        laser = np.zeros_like(self.background_e)
        win = self.laser_window(trace) if trace is not None else None
        if win is not None:
            laser[win.slices] = win.electrons
        return colour_frame(self.background_e, laser, self.sensor, self.colour, None)

    def sensor_frame(self, trace: LaserTrace | None, rng: np.random.Generator) -> np.ndarray:
        """A noisy digital frame as the camera delivers it, before storage (laser-free when
        ``trace`` is None): (H, W) grey, or (H, W, 3) RGB, demosaiced and white-balanced, for a colour
        camera."""
        img = self.noise.frame(rng)
        win = self.laser_window(trace, rng) if trace is not None else None
        if self.colour is None:
            if win is not None:
                img[win.slices] = self.sensor.expose(self.background_e[win.slices] + win.electrons, rng)
            return img
        if win is not None:
            win = win.padded(self.colour.halo_pad_px, img.shape[:2])
            electrons = channel_electrons(self.background_e[win.slices], win.electrons, self.colour)
            img[win.slices] = expose_rgb(electrons, self.sensor, rng)
        return processed(img, self.colour)

    def frame(self, trace: LaserTrace | None, rng: np.random.Generator) -> np.ndarray:
        """A noisy digital frame as stored (:meth:`sensor_frame`, then a colour camera's JPEG
        round trip when it stores JPEG)."""
        img = self.sensor_frame(trace, rng)
        return img if self.colour is None else stored(img, self.colour)


class _BackgroundShading:
    """Laser-free radiance of blocks of camera rays (room light: ambient plus a distant lamp)."""

    def __init__(self, scene):
        self.caster = scene.raycaster
        self.materials = scene.materials
        light = scene.lighting
        self.lamp_W_m2 = light.lamp_W_m2
        self.ambient = light.ambient_W_m2 / np.pi
        self.lamp_dir = np.asarray(light.lamp_direction, dtype=np.float64)
        self.backdrop = BACKDROP_ALBEDO * self.ambient
        self.spec = np.array([m.specular for m in self.materials])
        self.rough = np.array([m.roughness_rad for m in self.materials])

    def radiance(self, origin: np.ndarray, dirs: np.ndarray, flat: FlatHits | None = None, first: int = 0):
        """Radiance along rays ``origin`` (3,) + t ``dirs`` (n, 3), and the object hit (-1 on a miss);
        ``flat``, when given, receives the rays' flat hits as its rays ``first:first + n``."""
        n_rays = len(dirs)
        idx, hits = self.caster.first_hits(origin, dirs)
        radiance = np.full(n_rays, self.backdrop)
        obj = np.full(n_rays, -1, dtype=np.int64)
        if idx.size == 0:
            return radiance, obj
        p, n, ng, o = hits.point, hits.shading_normal, hits.normal, hits.obj
        albedo = _albedo(self.materials, o, p)
        out = albedo + self.spec[o] if self.spec.any() else albedo.copy()
        out *= self.ambient
        e_lamp = np.zeros(idx.size)
        if self.lamp_W_m2 > 0:
            lamp_dir = self.lamp_dir
            cos_l = n @ -lamp_dir
            cos_l[(cos_l < 0) | (ng @ lamp_dir >= 0)] = 0.0
            lit = np.flatnonzero(cos_l > 0)
            if lit.size:
                # shadow-ray origins p + ε ng (row gathers by np.take: half the time of p[lit])
                start = np.take(ng, lit, axis=0)
                start *= SURFACE_EPS_M
                start += np.take(p, lit, axis=0)
                shadow = self.caster.occluded(start, np.broadcast_to(-lamp_dir, (lit.size, 3)),
                                              np.full(lit.size, _FAR_M))
                cos_l[lit[shadow]] = 0.0
            e_lamp = self.lamp_W_m2 * cos_l
            out += albedo * e_lamp / np.pi
            shiny = np.flatnonzero(self.spec[o] > 0) if self.spec.any() else ()
            if len(shiny):
                view = -dirs[idx[shiny]]
                mirror = reflect(np.broadcast_to(lamp_dir, (len(shiny), 3)), n[shiny])
                out[shiny] += self.spec[o[shiny]] * e_lamp[shiny] * specular_lobe(
                    np.einsum("ij,ij->i", mirror, view), self.rough[o[shiny]])
        if flat is not None:
            rows = first + idx
            plane = (self.spec[o] == 0) & (np.abs(n - ng) <= NORMAL_TOL).all(axis=1)
            flat.normal[rows] = ng
            flat.offset_m[rows] = np.where(plane, np.einsum("ij,ij->i", ng, p), np.nan)
            flat.lamp_W_m2[rows] = e_lamp
        if idx.size == n_rays:
            return out, o
        radiance[idx] = out
        obj[idx] = o
        return radiance, obj

    def matte(self, obj: np.ndarray, p: np.ndarray, lamp_W_m2: np.ndarray) -> np.ndarray:
        """Radiance of matte hits of objects ``obj`` (n,) at ``p`` (n, 3) under lamp irradiance
        ``lamp_W_m2`` (n,), computed as :meth:`radiance` computes it."""
        albedo = _albedo(self.materials, obj, p)
        out = albedo * self.ambient
        if self.lamp_W_m2 > 0:
            out += albedo * lamp_W_m2 / np.pi
        return out


def _albedo(materials, obj: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Albedo at hit points ``p`` of objects ``obj``."""
    present = np.flatnonzero(np.bincount(obj, minlength=len(materials)))
    if len(present) == 1:
        return np.asarray(materials[present[0]].albedo_at(p), dtype=np.float64)
    albedo = np.empty(len(obj))
    for j in present:
        sel = np.flatnonzero(obj == j)
        albedo[sel] = materials[j].albedo_at(np.take(p, sel, axis=0))
    return albedo


def _subpixel_samples(centres: np.ndarray, s: int) -> np.ndarray:
    """``s × s`` sample positions per pixel (pixel i's samples are rows ``i*s²:(i+1)*s²``, row-major
    within the pixel: sub-row index first)."""
    offsets = (np.arange(s) + 0.5) / s - 0.5
    dv, du = np.meshgrid(offsets, offsets, indexing="ij")
    grid = np.column_stack([du.ravel(), dv.ravel()])
    return (centres[:, None, :] + grid[None]).reshape(-1, 2)


def _block_mean(fine: np.ndarray, s: int) -> np.ndarray:
    """Mean of each ``s × s`` block of an image, bit-identical to numpy's
    ``fine.reshape(h, s, w, s).mean(axis=(1, 3))``.

    numpy adds each block row (its ``s`` values in :func:`_pairwise_row_sum` order) into the
    result, block row after block row, then divides by ``s²``; but it runs an inner loop per
    block row of ``s`` values. Here the same additions, in the same order, are whole-image
    operations on strided views (6 instead of 26 ms on a 300 × 600 px window at ``s`` = 4),
    so laser windows stay bit-identical. A result one pixel wide is left to numpy: its
    iterator then merges a block's rows into one run of ``s²`` values, summed in another order.

    Parameters
    ----------
    fine : ndarray of shape (h * s, w * s), float32
    s : int
        Block size, pixels (1 to 32).

    Returns
    -------
    ndarray of shape (h, w), float32
    """
    h, w = fine.shape[0] // s, fine.shape[1] // s
    blocks = fine.reshape(h, s, w, s)
    if w == 1:
        return blocks.mean(axis=(1, 3))
    total = np.zeros((h, w), dtype=fine.dtype)
    for row in range(s):
        total += _pairwise_row_sum(blocks[:, row])
    # as numpy's mean: the count is an integer array scalar, so the division runs in float64
    return np.true_divide(total, np.intp(s * s), out=total, casting="unsafe")


def _pairwise_row_sum(a: np.ndarray) -> np.ndarray:
    """Sum over the last axis (at most 128 values) in the order of numpy's pairwise summation:
    fewer than 8 values one after the other; else 8 running sums over strides of 8, combined
    as ((0+1)+(2+3))+((4+5)+(6+7)), then the rest one after the other.

    Parameters
    ----------
    a : ndarray of shape (..., n)

    Returns
    -------
    ndarray of shape (...)
    """
    n = a.shape[-1]
    lanes = 1 if n < 8 else 8
    run = [a[..., j].copy() for j in range(lanes)]
    tail = n - n % lanes
    for i in range(lanes, tail, lanes):
        for j in range(lanes):
            run[j] += a[..., i + j]
    total = run[0] if lanes == 1 else ((run[0] + run[1]) + (run[2] + run[3])) + ((run[4] + run[5]) + (run[6] + run[7]))
    for i in range(tail, n):
        total += a[..., i]
    return total


def _edges(radiance: np.ndarray, obj: np.ndarray) -> np.ndarray:
    """Pixels that differ from a 4-neighbour in object or by more than EDGE_CONTRAST in radiance."""
    edge = np.zeros(radiance.shape, dtype=bool)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(1, None), slice(None, -1)
        ra, rb = radiance[tuple(a)], radiance[tuple(b)]
        diff = (obj[tuple(a)] != obj[tuple(b)]) | (np.abs(ra - rb) > EDGE_CONTRAST * np.maximum(ra, rb))
        edge[tuple(a)] |= diff
        edge[tuple(b)] |= diff
    return edge


def _speckle(shape, contrast: float, grain_px: float, rng: np.random.Generator) -> np.ndarray:
    """A speckle intensity field of mean 1 and contrast ``contrast`` (fully developed speckle is
    the squared modulus of a low-pass complex Gaussian field; it is mixed with 1 for partial
    contrast)."""
    import cv2

    field = rng.standard_normal((2, *shape)).astype(np.float32)
    sigma = grain_px / 2.0
    re = cv2.GaussianBlur(field[0], (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    im = cv2.GaussianBlur(field[1], (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    inten = re * re + im * im
    inten /= max(float(inten.mean()), 1e-30)
    return (1.0 + contrast * (inten - 1.0)).astype(np.float32)

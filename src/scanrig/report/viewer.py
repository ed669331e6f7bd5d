"""A self-contained 3-D viewer of a point cloud and its mesh for the HTML report: canvas 2-D, no library.

The cloud travels as base64 little-endian float32 arrays (centred and scaled to unit radius, so
float32 keeps ~1e-7 of the object size). The script fills an ``ImageData`` with a depth buffer:
the mesh's triangles first (flat grey, shaded by the angle of their normal to the line of sight,
rasterised with edge functions), then every point as a 2-4 px square coloured from a 256-entry
colour map (1 px over the mesh for a cloud of 5000 points or more), drawn where it is not behind the mesh by more than :data:`POINT_DEPTH_BIAS` (points
lie on the surface they measured). One typed-array pass per redraw, fast for 200 000 points and
as many triangles. Drag rotates, the wheel zooms, shift-drag pans; a selector shows mesh and
points, points only, or the mesh only.
"""

from __future__ import annotations

import base64
import html
import json

import numpy as np

#: Largest number of points shipped to the viewer (a random subsample beyond).
MAX_VIEWER_POINTS = 200_000
#: Colour-map range: these percentiles of each field, so that a few outliers do not wash it out.
COLOUR_PERCENTILES = (1.0, 99.0)
#: Colour range given to a field whose values are all equal.
COLOUR_MIN_SPAN = 1e-12
#: Largest number of mesh triangles shipped to the viewer (a random subset beyond, said in the page).
MAX_VIEWER_TRIANGLES = 300_000
#: A point is drawn when it is at most this far behind the mesh, in units of the scene's radius
#: (1 % of a 0.3 m scene is 3 mm: far beyond the points' errors, far less than a part's thickness).
POINT_DEPTH_BIAS = 0.01


def _b64(array: np.ndarray) -> str:
    return base64.b64encode(np.ascontiguousarray(array, dtype="<f4").tobytes()).decode("ascii")


def colour_lut(name: str = "viridis") -> str:
    """A matplotlib colour map as 256 RGB bytes, base64."""
    import matplotlib

    rgb = (matplotlib.colormaps[name](np.linspace(0.0, 1.0, 256))[:, :3] * 255).round().astype(np.uint8)
    return base64.b64encode(rgb.tobytes()).decode("ascii")


def subsample(n: int, max_points: int, rng: np.random.Generator) -> np.ndarray:
    """Sorted indices of at most ``max_points`` of ``n`` points, drawn without replacement."""
    if n <= max_points:
        return np.arange(n)
    return np.sort(rng.choice(n, max_points, replace=False))


def viewer_html(p_world: np.ndarray, fields: list[tuple[str, str, np.ndarray]], element_id: str = "cloud",
                mesh: tuple[np.ndarray, np.ndarray] | None = None, size_px: tuple[int, int] = (960, 640)) -> str:
    """HTML of the viewer (canvas, display and colour selectors, legend and script).

    Parameters
    ----------
    p_world : (N, 3) float array
        Points, world frame, metres (already subsampled).
    fields : list of (label, unit, (N,) float array)
        Per-point values the user can colour by, in display units; the first is shown first.
        NaN values are drawn grey.
    element_id : str
        Prefix of the element ids (one viewer per id).
    mesh : ((V, 3) float array, (F, 3) int array), optional
        Vertices (world frame, metres) and triangles drawn under the points (already capped).
    size_px : (int, int)
        Canvas width and height, pixels.

    Returns
    -------
    str
        An HTML fragment.
    """
    p = np.asarray(p_world, np.float64)
    extent = np.concatenate([p, np.asarray(mesh[0], np.float64)]) if mesh is not None and len(mesh[1]) else p
    centre = (extent.min(axis=0) + extent.max(axis=0)) / 2 if len(extent) else np.zeros(3)
    radius = float(np.max(np.linalg.norm(extent - centre, axis=1))) if len(extent) else 1.0
    radius = radius if radius > 0 else 1.0
    entries = []
    for label, unit, values in fields:
        v = np.asarray(values, np.float64)
        finite = v[np.isfinite(v)]
        lo, hi = (np.percentile(finite, COLOUR_PERCENTILES) if finite.size else (0.0, 1.0))
        hi = hi if hi > lo else lo + COLOUR_MIN_SPAN   # a constant field still needs a range
        entries.append({"label": label, "unit": unit, "lo": float(lo), "hi": float(hi), "values": _b64(v)})
    has_mesh = mesh is not None and len(mesh[1]) > 0
    data = {"n": int(len(p)), "xyz": _b64((p - centre) / radius), "centre_m": centre.tolist(), "radius_m": radius,
            "fields": entries, "lut": colour_lut(), "bias": POINT_DEPTH_BIAS,
            "mesh_xyz": _b64((np.asarray(mesh[0], np.float64) - centre) / radius) if has_mesh else "",
            "mesh_faces": base64.b64encode(np.ascontiguousarray(mesh[1], dtype="<u4").tobytes()).decode("ascii")
            if has_mesh else ""}
    options = "".join(f'<option value="{i}">{html.escape(e["label"])}</option>' for i, e in enumerate(entries))
    shows = ["mesh and points", "points", "mesh"] if has_mesh else ["points"]
    show_options = "".join(f'<option value="{html.escape(x)}">{html.escape(x)}</option>' for x in shows)
    i = html.escape(element_id)
    return (_TEMPLATE.replace("@ID@", i).replace("@OPTIONS@", options).replace("@SHOW@", show_options)
            .replace("@W@", str(int(size_px[0]))).replace("@H@", str(int(size_px[1])))
            .replace("@DATA@", json.dumps(data).replace("</", "<\\/")))


_TEMPLATE = """
<div class="viewer" id="@ID@-box">
  <canvas id="@ID@" width="@W@" height="@H@"></canvas>
  <div class="viewer-bar">
    <label>show <select id="@ID@-show">@SHOW@</select></label>
    <label>colour by <select id="@ID@-field">@OPTIONS@</select></label>
    <canvas id="@ID@-legend" width="420" height="46"></canvas>
    <span class="hint">drag: rotate &middot; wheel: zoom &middot; shift-drag: pan &middot; double-click: reset</span>
  </div>
</div>
<script>
(function () {
  "use strict";
  const DATA = @DATA@;
  function bytes(b64) {
    const s = atob(b64), out = new Uint8Array(s.length);
    for (let i = 0; i < s.length; i++) out[i] = s.charCodeAt(i);
    return out;
  }
  const floats = (b64) => new Float32Array(bytes(b64).buffer);
  const xyz = floats(DATA.xyz), n = DATA.n, lut = bytes(DATA.lut);
  const fields = DATA.fields.map((f) => Object.assign({}, f, {v: floats(f.values)}));
  const canvas = document.getElementById("@ID@"), ctx = canvas.getContext("2d");
  const legend = document.getElementById("@ID@-legend"), lctx = legend.getContext("2d");
  const select = document.getElementById("@ID@-field"), show = document.getElementById("@ID@-show");
  const mxyz = DATA.mesh_xyz ? floats(DATA.mesh_xyz) : new Float32Array(0);
  const faces = DATA.mesh_faces ? new Uint32Array(bytes(DATA.mesh_faces).buffer) : new Uint32Array(0);
  const nv = mxyz.length / 3, mv = new Float32Array(3 * nv);
  const W = canvas.width, H = canvas.height;
  const image = ctx.createImageData(W, H), pix = new Uint32Array(image.data.buffer);
  const depth = new Float32Array(W * H), pdepth = new Float32Array(W * H);   // mesh's, points' depth
  const colour = new Uint32Array(n);
  const BG = 0xff202020, GREY = 0xff909090;
  const SPLAT = n < 5000 ? 4 : n < 50000 ? 3 : 2;          // sparse clouds get bigger dots
  const SPLAT_ON_MESH = n < 5000 ? SPLAT : 1;               // a dense cloud over its mesh leaves the mesh visible
  let yaw = 0.6, pitch = -0.5, zoom = 1.0, panX = 0, panY = 0, field = 0;

  function recolour() {
    const f = fields[field], span = f.hi - f.lo;
    for (let i = 0; i < n; i++) {
      const x = f.v[i];
      if (!Number.isFinite(x)) { colour[i] = GREY; continue; }
      const k = Math.max(0, Math.min(255, Math.round(255 * (x - f.lo) / span))) * 3;
      colour[i] = 0xff000000 | (lut[k + 2] << 16) | (lut[k + 1] << 8) | lut[k];
    }
    drawLegend(f);
  }
  function drawLegend(f) {
    const w = legend.width;
    lctx.clearRect(0, 0, w, legend.height);
    for (let x = 0; x < w; x++) {
      const k = Math.round(255 * x / (w - 1)) * 3;
      lctx.fillStyle = "rgb(" + lut[k] + "," + lut[k + 1] + "," + lut[k + 2] + ")";
      lctx.fillRect(x, 0, 1, 18);
    }
    lctx.fillStyle = "#222"; lctx.font = "12px sans-serif";
    const fmt = (v) => Math.abs(v) >= 100 || Math.abs(v) < 0.01 ? v.toExponential(2) : v.toPrecision(3);
    lctx.textAlign = "left"; lctx.fillText(fmt(f.lo), 0, 34);
    lctx.textAlign = "right"; lctx.fillText(fmt(f.hi) + " " + f.unit, w, 34);
    lctx.textAlign = "center"; lctx.fillText(f.label, w / 2, 34);
  }
  function drawMesh(cy, sy, cp, sp, s, ox, oy) {
    for (let i = 0; i < nv; i++) {                           // vertices to screen (u, v) and depth
      const x = mxyz[3 * i], y = mxyz[3 * i + 1], z = mxyz[3 * i + 2];
      const x1 = cy * x - sy * y, y1 = sy * x + cy * y;
      mv[3 * i] = ox + s * x1; mv[3 * i + 1] = oy - s * (sp * y1 + cp * z); mv[3 * i + 2] = cp * y1 - sp * z;
    }
    for (let f = 0; f < faces.length; f += 3) {
      const a = 3 * faces[f], b = 3 * faces[f + 1], c = 3 * faces[f + 2];
      const ax = mv[a], ay = mv[a + 1], bx = mv[b], by = mv[b + 1], cx = mv[c], cy2 = mv[c + 1];
      const area = (bx - ax) * (cy2 - ay) - (by - ay) * (cx - ax);
      if (Math.abs(area) < 1e-9) continue;
      // Shade: |cos| of the angle between the face normal and the line of sight (screen z = depth).
      const e1x = bx - ax, e1y = by - ay, e1z = (mv[b + 2] - mv[a + 2]) * s;
      const e2x = cx - ax, e2y = cy2 - ay, e2z = (mv[c + 2] - mv[a + 2]) * s;
      const nx = e1y * e2z - e1z * e2y, ny = e1z * e2x - e1x * e2z, nz = e1x * e2y - e1y * e2x;
      const g = Math.round(70 + 150 * Math.abs(nz) / Math.hypot(nx, ny, nz));
      const colourG = 0xff000000 | (g << 16) | (g << 8) | g;
      const u0 = Math.max(0, Math.floor(Math.min(ax, bx, cx))), u1 = Math.min(W - 1, Math.ceil(Math.max(ax, bx, cx)));
      const v0 = Math.max(0, Math.floor(Math.min(ay, by, cy2))), v1 = Math.min(H - 1, Math.ceil(Math.max(ay, by, cy2)));
      for (let v = v0; v <= v1; v++) {
        for (let u = u0; u <= u1; u++) {
          const w0 = ((bx - u) * (cy2 - v) - (by - v) * (cx - u)) / area;
          const w1 = ((cx - u) * (ay - v) - (cy2 - v) * (ax - u)) / area;
          const w2 = 1 - w0 - w1;
          if (w0 < 0 || w1 < 0 || w2 < 0) continue;
          const d = w0 * mv[a + 2] + w1 * mv[b + 2] + w2 * mv[c + 2], j = v * W + u;
          if (d < depth[j]) { depth[j] = d; pix[j] = colourG; }
        }
      }
    }
  }
  function draw() {
    pix.fill(BG); depth.fill(Infinity); pdepth.fill(Infinity);
    const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    const s = 0.45 * Math.min(W, H) * zoom, ox = W / 2 + panX, oy = H / 2 + panY;
    const mode = show.value;
    if (mode !== "points") drawMesh(cy, sy, cp, sp, s, ox, oy);
    const bias = mode === "points" ? 0 : DATA.bias, splat = mode === "points" ? SPLAT : SPLAT_ON_MESH;
    for (let i = 0; i < (mode === "mesh" ? 0 : n); i++) {
      const x = xyz[3 * i], y = xyz[3 * i + 1], z = xyz[3 * i + 2];
      const x1 = cy * x - sy * y, y1 = sy * x + cy * y;      // yaw about world z (up)
      const y2 = cp * y1 - sp * z, z2 = sp * y1 + cp * z;    // pitch about the screen x axis
      const u = Math.round(ox + s * x1), v = Math.round(oy - s * z2);
      if (u < 0 || v < 0 || u > W - splat || v > H - splat) continue;
      const c = colour[i];
      for (let dv = 0; dv < splat; dv++) {                   // splat x splat square, nearest wins
        for (let du = 0, j = (v + dv) * W + u; du < splat; du++, j++) {
          if (y2 < depth[j] + bias && y2 < pdepth[j]) { pdepth[j] = y2; pix[j] = c; }
        }
      }
    }
    ctx.putImageData(image, 0, 0);
    ctx.fillStyle = "#ddd"; ctx.font = "12px sans-serif";
    ctx.fillText(n + " points, " + faces.length / 3 + " triangles, radius " + (1000 * DATA.radius_m).toFixed(1)
                 + " mm", 8, H - 8);
  }
  let drag = null;
  canvas.addEventListener("mousedown", (e) => { drag = {x: e.clientX, y: e.clientY, pan: e.shiftKey}; });
  window.addEventListener("mouseup", () => { drag = null; });
  window.addEventListener("mousemove", (e) => {
    if (!drag) return;
    const dx = e.clientX - drag.x, dy = e.clientY - drag.y;
    drag.x = e.clientX; drag.y = e.clientY;
    if (drag.pan) { panX += dx; panY += dy; } else { yaw += 0.01 * dx; pitch += 0.01 * dy; }
    draw();
  });
  canvas.addEventListener("wheel", (e) => { e.preventDefault(); zoom *= Math.exp(-0.001 * e.deltaY); draw(); },
                          {passive: false});
  canvas.addEventListener("dblclick", () => { yaw = 0.6; pitch = -0.5; zoom = 1; panX = panY = 0; draw(); });
  select.addEventListener("change", () => { field = Number(select.value); recolour(); draw(); });
  show.addEventListener("change", draw);
  recolour(); draw();
})();
</script>
"""

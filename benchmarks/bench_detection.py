"""Laser trace detection: accuracy against the Cramér–Rao bound, honesty of sigma, candidates, speed.

Run ``python benchmarks/bench_detection.py`` (about 3 minutes) or with ``--quick`` (under a minute);
``--stages`` prints only where the stripe frame's time goes.
Every figure is measured in this run on synthetic 8-bit frames (pixel-integrated Gaussians,
amplitude 180 DN over 10 DN, noise 2 DN, rounded), next to:

- the Cramér–Rao bound of the centre (all of peak, width, background unknown; noise including
  rounding) computed for the same true positions;
- the baseline: the 7-pixel centre of gravity used by Horus and FabScan (7 pixels, or 7 × 7 for
  spots, centred on the brightest pixel; weights = value minus a threshold of background + 3σ,
  clipped at 0), run on the same images;
- for speed, the time to read the frame once (``image.max()``), the floor of any detector.

The "dark frame" rows subtract a laser-off frame of the same background and noise, which switches
on the per-pixel noise model (:class:`scanrig.laser.noise.NoiseModel`, fitted in every frame).

Timings are on one core (OpenCV and BLAS limited to one thread): median wall and median and best
CPU time (``time.process_time``, all threads of the process) of repeated runs.
"""

from __future__ import annotations

import os

# One core, whatever the caller's environment says (set before NumPy and OpenCV are imported).
for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402
from contextlib import ExitStack  # noqa: E402
from unittest import mock  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from laser.synth import spot_image, stripe_image  # noqa: E402

from scanrig.laser import fit, stripes  # noqa: E402
from scanrig.laser.crb import crb_spot, crb_stripe, effective_noise  # noqa: E402
from scanrig.laser.spots import detect_spots  # noqa: E402
from scanrig.laser.stripes import detect_stripe  # noqa: E402

AMPLITUDE, BACKGROUND, NOISE = 180.0, 10.0, 2.0
SHAPE = (1024, 1280)
WIDTHS = (0.8, 1.0, 1.5, 2.0, 2.5)
COG_HALF = 3  # 7 pixels
SNR_MIN = 10.0  # recall is required for candidates at least this bright (peak / noise σ)
N_BIAS_BINS = 10


def cog_rows(img: np.ndarray, threshold: float) -> np.ndarray:
    """Baseline stripe centre per row: 7-px centre of gravity around the row maximum."""
    rows = img.astype(np.float64)
    peak = np.clip(np.argmax(rows, axis=1), COG_HALF, rows.shape[1] - 1 - COG_HALF)
    idx = peak[:, None] + np.arange(-COG_HALF, COG_HALF + 1)
    w = np.clip(np.take_along_axis(rows, idx, axis=1) - threshold, 0, None)
    return (w * idx).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-12)


def cog_spots(img: np.ndarray, u: np.ndarray, v: np.ndarray, threshold: float):
    """Baseline spot centres: 7 × 7 centre of gravity around the brightest pixel near each spot."""
    offs = np.arange(-COG_HALF, COG_HALF + 1)
    f = img.astype(np.float64)
    ui, vi = np.rint(u).astype(int), np.rint(v).astype(int)
    near = f[vi[:, None, None] + offs[None, :, None], ui[:, None, None] + offs[None, None, :]]
    k = near.reshape(len(u), -1).argmax(axis=1)
    vc, uc = vi + offs[k // offs.size], ui + offs[k % offs.size]
    win = f[vc[:, None, None] + offs[None, :, None], uc[:, None, None] + offs[None, None, :]]
    w = np.clip(win - threshold, 0, None)
    tot = np.maximum(w.sum(axis=(1, 2)), 1e-12)
    return uc + (w.sum(axis=1) * offs).sum(axis=1) / tot, vc + (w.sum(axis=2) * offs).sum(axis=1) / tot


def worst_bias(err: np.ndarray, offset: np.ndarray) -> float:
    bins = np.minimum(((offset + 0.5) * N_BIAS_BINS).astype(int), N_BIAS_BINS - 1)
    return max(abs(err[bins == b].mean()) for b in range(N_BIAS_BINS))


def stripe_accuracy(rng, sigma: float, n_frames: int) -> dict:
    errs, offs, ratios, base, base_offs = [], [], [], [], []
    for _ in range(n_frames):
        centres = 640.0 + rng.uniform(-0.5, 0.5, SHAPE[0])
        img = stripe_image(SHAPE, lambda lines: centres[lines.astype(int)], rng, AMPLITUDE, sigma, BACKGROUND, NOISE)
        t = detect_stripe(img)
        t = t.filter(np.asarray(t["rank"].to_numpy() == 0))
        line = t["line"].to_numpy()
        e = t["u"].to_numpy() - centres[line]
        errs.append(e)
        offs.append(centres[line] - 640.0)
        ratios.append(e / t["sigma_px"].to_numpy())
        base.append(cog_rows(img, BACKGROUND + 3 * NOISE) - centres)
        base_offs.append(centres - 640.0)
    err, off, b = np.concatenate(errs), np.concatenate(offs), np.concatenate(base)
    bound = crb_stripe(AMPLITUDE, sigma, off, effective_noise(NOISE))
    return {"n": err.size, "found": err.size / (n_frames * SHAPE[0]), "rms": _rms(err), "bias": worst_bias(err, off),
            "crb": _rms(bound), "z": float(np.std(np.concatenate(ratios))), "cog_rms": _rms(b),
            "cog_bias": worst_bias(b, np.concatenate(base_offs))}


def spot_accuracy(rng, sigma: float, n_frames: int) -> dict:
    errs, base, offs, ratios, found, total = [], [], [], [], 0, 0
    gv, gu = np.meshgrid(np.arange(30, SHAPE[0] - 20, 40), np.arange(30, SHAPE[1] - 20, 40), indexing="ij")
    for _ in range(n_frames):
        u = gu.ravel() + rng.uniform(-0.5, 0.5, gu.size)
        v = gv.ravel() + rng.uniform(-0.5, 0.5, gv.size)
        img = spot_image(SHAPE, [(a, b, AMPLITUDE, sigma, sigma) for a, b in zip(u, v)], rng, BACKGROUND, NOISE)
        t = detect_spots(img, max_candidates=10_000)
        du = t["u"].to_numpy()[:, None] - u[None, :]
        dv = t["v"].to_numpy()[:, None] - v[None, :]
        j = np.argmin(du**2 + dv**2, axis=1)
        rows = np.arange(j.size)
        eu = du[rows, j]
        found += len(np.unique(j[np.hypot(eu, dv[rows, j]) < 0.5]))
        total += u.size
        errs.append(eu)
        ratios.append(eu / np.sqrt(t["cov_uu"].to_numpy()))
        offs.append(np.stack([u[j] - np.rint(u[j]), v[j] - np.rint(v[j])], axis=1))
        bu, _ = cog_spots(img, u, v, BACKGROUND + 3 * NOISE)
        base.append(np.stack([bu - u, u - np.rint(u)], axis=1))
    err, off = np.concatenate(errs), np.concatenate(offs)
    b = np.concatenate(base)
    bound = crb_spot(AMPLITUDE, sigma, off[:, 0], off[:, 1], effective_noise(NOISE))
    return {"n": err.size, "rms": _rms(err), "bias": worst_bias(err, off[:, 0]), "crb": _rms(bound),
            "z": float(np.std(np.concatenate(ratios))), "cog_rms": _rms(b[:, 0]),
            "cog_bias": worst_bias(b[:, 0], b[:, 1]),
            "found": found / total}


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def candidates(rng, n_frames: int, n_noise_frames: int) -> dict:
    """Recall of a spot and a 30-100 % reflection, of SNR-10 spots and stripe lines (σ = 0.8-2.5 px,
    random offsets), and false candidates in frames of noise alone."""
    hits, wanted = 0, 0
    for _ in range(n_frames):
        u0, v0 = rng.uniform(40, 150, 2)
        ratio = rng.uniform(0.3, 1.0)
        ang, dist = rng.uniform(0, 2 * np.pi), rng.uniform(6, 30)
        truth = [(u0, v0), (u0 + dist * np.cos(ang), v0 + dist * np.sin(ang))]
        img = spot_image((192, 192), [(*truth[0], AMPLITUDE, 1.5, 1.5), (*truth[1], ratio * AMPLITUDE, 1.5, 1.5)],
                         rng, BACKGROUND, NOISE)
        t = detect_spots(img)
        for tu, tv in truth:
            wanted += 1
            hits += int(np.any(np.hypot(t["u"].to_numpy() - tu, t["v"].to_numpy() - tv) < 0.5))
    snr10 = SNR_MIN * effective_noise(NOISE)
    spot_hits, spot_n, line_hits, line_n = 0, 0, 0, 0
    gv, gu = np.meshgrid(np.arange(30, 200, 40), np.arange(30, 280, 40), indexing="ij")
    for k in range(n_frames // 10):
        sigma = WIDTHS[k % len(WIDTHS)]
        u, v = gu.ravel() + rng.uniform(-0.5, 0.5, gu.size), gv.ravel() + rng.uniform(-0.5, 0.5, gv.size)
        t = detect_spots(spot_image((224, 304), [(a, b, snr10, sigma, sigma) for a, b in zip(u, v)], rng,
                                    BACKGROUND, NOISE), max_candidates=1000)
        d = np.hypot(t["u"].to_numpy()[:, None] - u[None, :], t["v"].to_numpy()[:, None] - v[None, :])
        spot_hits += int((d.min(axis=0, initial=np.inf) < 1.0).sum())
        spot_n += u.size
        centres = 150.0 + rng.uniform(-0.5, 0.5, 256)
        t = detect_stripe(stripe_image((256, 300), lambda lines: centres[lines.astype(int)], rng, snr10, sigma,
                                       BACKGROUND, NOISE))
        line = t["line"].to_numpy()
        line_hits += len(np.unique(line[np.abs(t["u"].to_numpy() - centres[line]) < 1.0]))
        line_n += centres.size
    false_spot = sum(len(detect_spots(spot_image(SHAPE, [], rng, BACKGROUND, NOISE))) for _ in range(n_noise_frames))
    false_stripe = sum(len(detect_stripe(spot_image(SHAPE, [], rng, BACKGROUND, NOISE))) for _ in range(n_noise_frames))
    # with a laser-off frame subtracted (its noise is the same in every frame; per-pixel noise model)
    dark = spot_image(SHAPE, [], rng, BACKGROUND, NOISE)
    false_dark = sum(len(detect_spots(spot_image(SHAPE, [], rng, BACKGROUND, NOISE), dark=dark))
                     + len(detect_stripe(spot_image(SHAPE, [], rng, BACKGROUND, NOISE), dark=dark))
                     for _ in range(n_noise_frames))
    return {"recall": hits / wanted, "n": wanted, "spot10": spot_hits / spot_n, "spot10_n": spot_n,
            "false_dark_per_100": 100 * false_dark / n_noise_frames,
            "line10": line_hits / line_n, "line10_n": line_n,
            "false_spot_per_100": 100 * false_spot / n_noise_frames,
            "false_stripe_per_100": 100 * false_stripe / n_noise_frames, "noise_frames": n_noise_frames}


def timing(fn, repeats: int) -> tuple[float, float, float]:
    """Median wall, median CPU and best CPU time of ``fn()``, milliseconds (the best is the least
    disturbed by other processes)."""
    fn()
    wall, cpu = [], []
    for _ in range(repeats):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return 1e3 * float(np.median(wall)), 1e3 * float(np.median(cpu)), 1e3 * float(np.min(cpu))


def speed(rng, repeats: int) -> dict:
    spot = spot_image(SHAPE, [(640.3, 500.7, AMPLITUDE, 1.5, 1.5)], rng, BACKGROUND, NOISE)
    stripe = stripe_image(SHAPE, lambda lines: 600.3 + 0.1 * lines, rng, AMPLITUDE, 1.5, BACKGROUND, NOISE)
    dark = spot_image(SHAPE, [], rng, BACKGROUND, NOISE)
    return {"floor": timing(lambda: spot.max(), repeats), "spot": timing(lambda: detect_spots(spot), repeats),
            "stripe": timing(lambda: detect_stripe(stripe), repeats),
            "spot_dark": timing(lambda: detect_spots(spot, dark=dark), repeats),
            "stripe_dark": timing(lambda: detect_stripe(stripe, dark=dark), repeats),
            "cog_stripe": timing(lambda: cog_rows(stripe, BACKGROUND + 3 * NOISE), repeats)}


#: Steps of detect_stripe timed by --stages, by the module and name they are called by, and their
#: labels (indented: part of the step above).
STAGES = {(stripes, "prepare_image"): "signal, noise and background", (stripes, "prescan"): "pre-scan",
          (stripes, "_crossings"): "candidates, both directions",
          (stripes, "_fit_along"): "fit of the clipped candidates", (stripes, "_line_windows"): "the others' windows",
          (stripes, "_start"): "  start values", (stripes, "_fit_lines"): "their fit, both directions",
          (stripes, "fit_batch"): "  Levenberg-Marquardt", (stripes, "parameter_covariance"): "  covariance",
          (fit, "erf"): "  erf of the model, in both fits",
          (stripes, "make_table"): "table"}


def stage_times(rng, repeats: int) -> tuple[dict[str, float], float]:
    """Median CPU time, ms, of each of :data:`STAGES` (by label) and of the whole detect_stripe on
    the speed frame: each step wrapped by a timer where detect_stripe looks it up (the calls are
    unchanged)."""
    stripe = stripe_image(SHAPE, lambda lines: 600.3 + 0.1 * lines, rng, AMPLITUDE, 1.5, BACKGROUND, NOISE)
    spent = dict.fromkeys(STAGES.values(), 0.0)

    def timed(label, fn):
        def run(*args, **kwargs):
            c0 = time.process_time()
            out = fn(*args, **kwargs)
            spent[label] += time.process_time() - c0
            return out
        return run

    with ExitStack() as patches:
        for (module, name), label in STAGES.items():
            patches.enter_context(mock.patch.object(module, name, timed(label, getattr(module, name))))
        detect_stripe(stripe)
        per_run, total = {label: [] for label in spent}, []
        for _ in range(repeats):
            spent.update(dict.fromkeys(spent, 0.0))
            c0 = time.process_time()
            detect_stripe(stripe)
            total.append(time.process_time() - c0)
            for label, t in spent.items():
                per_run[label].append(t)
    return {label: 1e3 * float(np.median(t)) for label, t in per_run.items()}, 1e3 * float(np.median(total))


def print_stages(rng, repeats: int) -> None:
    times, total = stage_times(rng, repeats)
    print(f"\ndetect_stripe on the speed frame by stage, median CPU of {repeats} runs, ms and share (one core; "
          f"load {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
    for label, t in times.items():
        print(f"  {label:34}{t:8.2f}{100 * t / total:7.1f} %")
    print(f"  {'detect_stripe':34}{total:8.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer frames (under a minute)")
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--stages", action="store_true", help="only the stripe frame's time by stage (ms)")
    args = parser.parse_args()
    cv2.setNumThreads(1)
    rng = np.random.default_rng(args.seed)
    if args.stages:
        print_stages(rng, 200)
        return
    n_acc, n_cand, n_noise, reps = (1, 100, 20, 20) if args.quick else (4, 500, 100, 100)
    print(f"bench_detection  seed={args.seed}  quick={args.quick}  frames {SHAPE[1]}x{SHAPE[0]} 8-bit, "
          f"A={AMPLITUDE:g} DN over {BACKGROUND:g}, noise {NOISE:g} DN (+rounding)")
    print("\nAccuracy (u error, px; CRB = Cramér–Rao bound; z = std of error / reported sigma, target 0.8-1.25)")
    print(f"{'kind':7}{'sigma':>6}{'n':>7}{'found':>7}{'RMS':>9}{'CRB':>9}{'RMS/CRB':>9}{'bias':>8}{'z':>7}"
          f"{'COG7 RMS':>10}{'COG/CRB':>9}{'COG bias':>10}")
    for kind, fn in (("stripe", stripe_accuracy), ("spot", spot_accuracy)):
        for s in WIDTHS:
            r = fn(rng, s, n_acc)
            print(f"{kind:7}{s:6.1f}{r['n']:7d}{r['found']:7.3f}{r['rms']:9.4f}{r['crb']:9.4f}"
                  f"{r['rms'] / r['crb']:9.3f}{r['bias']:8.4f}{r['z']:7.3f}{r['cog_rms']:10.4f}"
                  f"{r['cog_rms'] / r['crb']:9.2f}{r['cog_bias']:10.4f}")
    c = candidates(rng, n_cand, n_noise)
    print(f"\nCandidates (recall target >= 0.99 at SNR >= 10; false target <= 1 per 100 frames)")
    print(f"  recall, spot + 30-100 % reflection (SNR 27-90): {c['recall']:.4f} of {c['n']}")
    print(f"  recall, isolated spots at SNR 10, sigma 0.8-2.5 px: {c['spot10']:.4f} of {c['spot10_n']}")
    print(f"  recall, stripe lines at SNR 10, sigma 0.8-2.5 px:   {c['line10']:.4f} of {c['line10_n']}")
    print(f"  false candidates per 100 noise-only 1280x1024 frames: spot {c['false_spot_per_100']:.1f}, "
          f"stripe {c['false_stripe_per_100']:.1f} ({c['noise_frames']} frames each)")
    print(f"  ... with a dark frame subtracted: spot + stripe {c['false_dark_per_100']:.1f}")
    t = speed(rng, reps)
    print(f"\nSpeed, one 1280x1024 8-bit frame, one core (OpenCV threads {cv2.getNumThreads()}, "
          f"OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}), ms (median wall under the current load, "
          f"median and best CPU of {reps} runs)")
    print(f"{'task':28}{'wall':>8}{'cpu':>8}{'best':>8}{'x floor':>9}{'target':>8}")
    for name, key, target in (("read once (image.max)", "floor", ""), ("detect_spots", "spot", "5"),
                              ("detect_stripe", "stripe", "4"), ("detect_spots, dark frame", "spot_dark", ""),
                              ("detect_stripe, dark frame", "stripe_dark", ""),
                              ("COG7 baseline, stripe rows", "cog_stripe", "")):
        wall, cpu, best = t[key]
        print(f"{name:28}{wall:8.2f}{cpu:8.2f}{best:8.2f}{best / t['floor'][2]:9.1f}{target:>8}")
    print(f"detect_stripe over the COG7 baseline, median CPU in this run: {t['stripe'][1] / t['cog_stripe'][1]:.1f}x")
    print(f"\nload average during the run: {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs")


if __name__ == "__main__":
    main()

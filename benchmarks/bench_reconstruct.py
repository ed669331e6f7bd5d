"""Reconstruction benchmark: every acceptance figure of issue 6 in one run.

Run from the repository root::

    python benchmarks/bench_reconstruct.py [--quick] [--session SIM_SESSION ...]

1. Triangulation speed on one core (3-view points), against the baseline of looping
   ``cv2.triangulatePoints`` over the camera pairs (pinhole cameras, so that both start from the
   same pixels), and accuracy at 0.3 px against the Gauss–Newton optimum.
2. Honest uncertainty: spread of the whitened errors over a synthetic spot scan.
3. Reflection rejection on synthetic traces (3 and 4 cameras, 30 % of camera-frames with a
   reflection).
4. End to end on simulator sessions given with ``--session`` (after ``scanrig simulate`` and
   ``scanrig detect``): with the true rig (``truth/rig.toml``) and, when present, the session's own
   calibration (``rig.toml``), stripes with the default precision cut and without; distance to
   the true surface and rejection of the candidates that lie on the projection of a true
   secondary hit (``truth/frames.csv``). ``--shiny DIR`` adds the
   issue 6 shiny-part session, built in ``DIR/shiny4-seed<S>`` when missing (:data:`SHINY`: scene
   ``shiny``, 4 cameras, 300 spot frames, calibrated by scanrig from 12 cube shots; ~4 min per
   seed on 2 cores); ``--shiny-seed S`` (repeatable, default 7) picks the noise and calibration
   seeds. The beam raster is the same for every seed, so seeds differ in noise, in the
   calibration and in which faint glints the detector reports.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # one core, as the acceptance figure says

import argparse
import csv
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # for tests.reconstruct.synth

from scanrig.geometry.triangulation import triangulate  # noqa: E402
from scanrig.io.rig_file import load_rig  # noqa: E402
from scanrig.laser.traces import read_traces  # noqa: E402
from scanrig.reconstruct.candidates import frame_order  # noqa: E402
from scanrig.reconstruct.correspondence import FrameStatus  # noqa: E402
from scanrig.errors import InputError  # noqa: E402
from scanrig.io.session import Session, read_image  # noqa: E402
from scanrig.reconstruct.evaluate import distance_statistics, load_truth_surface, rig_alignment  # noqa: E402
from scanrig.reconstruct.stereo import stereo_rig_points  # noqa: E402
from scanrig.reconstruct.stripes import reconstruct_stripes  # noqa: E402
from scanrig.reconstruct.spots import reconstruct_spots  # noqa: E402
from tests.reconstruct.synth import (  # noqa: E402
    height_field,
    observe,
    points_in_cube,
    reflection_outcome,
    ring_rig,
    spot_traces,
    stripe_traces,
)

SIGMA_PX = 0.3
#: The issue 6 shiny session: scene, cameras, spot frames, calibration shots (the seed is an option).
SHINY = dict(scene="shiny", cameras=4, frames=300, shots=12)
#: Distance from a true secondary hit's projection within which a candidate counts as that
#: reflection (pixels); detection noise is ~0.1 px, spot width ~2 px.
REFLECTION_MATCH_PX = 3.0


def _best_time(fn, repeats):
    """Best CPU time of the calling process (seconds) over ``repeats`` runs, and the result.

    CPU time, not wall time: on a machine shared with other jobs the wall clock counts the time
    the process waits for a core; with one thread, CPU time is the single-core cost.
    """
    best = np.inf
    for _ in range(repeats):
        t0 = time.process_time()
        out = fn()
        best = min(best, time.process_time() - t0)
    return best, out


def _rms(e):
    """RMS norm of the error rows that are finite."""
    e = e[np.all(np.isfinite(e), axis=1)]
    return float(np.sqrt(np.mean(np.sum(e**2, axis=1))))


def bench_triangulation(n, repeats):
    import cv2

    cv2.setNumThreads(1)
    rng = np.random.default_rng(1)
    rig = ring_rig(model="pinhole")
    p_true = points_in_cube(rng, n)
    q = observe(rig, p_true, rng, SIGMA_PX)
    seen = np.all(np.isfinite(q), axis=(0, 2))  # keep points inside every image for both methods
    p_true, q = p_true[seen], q[:, seen]
    n = int(seen.sum())
    cams = rig.cameras
    P = [c.K @ np.c_[c.cam_from_world.R, c.cam_from_world.t] for c in cams]
    pairs = [(i, j) for i in range(len(cams)) for j in range(i + 1, len(cams))]

    def cv2_pairs():
        acc = np.zeros((n, 3))
        for i, j in pairs:
            X = cv2.triangulatePoints(P[i], P[j], q[i].T.copy(), q[j].T.copy())
            acc += (X[:3] / X[3]).T
        return acc / len(pairs)

    t_cv, p_cv = _best_time(cv2_pairs, repeats)
    t_fast, (p_fast, _) = _best_time(lambda: triangulate(rig, q, sigma_px=SIGMA_PX, refine=False), repeats)
    # The reconstruction pipeline passes full pixel covariances (traces.parquet's cov_uu/uv/vv).
    cov_px = np.zeros(q.shape[:2] + (2, 2))
    cov_px[..., 0, 0] = cov_px[..., 1, 1] = SIGMA_PX**2
    t_cov, (p_cov, _) = _best_time(lambda: triangulate(rig, q, cov_px=cov_px, refine=False), repeats)
    t_gn, (p_gn, _) = _best_time(lambda: triangulate(rig, q, sigma_px=SIGMA_PX, refine=True), 1)
    rig_d = ring_rig()
    q_d = observe(rig_d, p_true, rng, SIGMA_PX)
    t_dist, _ = _best_time(lambda: triangulate(rig_d, q_d, sigma_px=SIGMA_PX, refine=False), 1)

    print(f"\n## 1. Triangulation, {n} three-view points, one thread, CPU time "
          "(machine shared, so timings are pessimistic)\n")
    print("| method | Mpoints/s | ratio vs cv2 pairs | RMS error (mm) | RMS / GN optimum |")
    print("|---|---|---|---|---|")
    rms_gn = _rms(p_gn - p_true)
    rows = [("cv2.triangulatePoints looped over 3 pairs, averaged (baseline)", t_cv, p_cv),
            ("scanrig closed form (refine=False), pinhole", t_fast, p_fast),
            ("scanrig closed form (refine=False), pinhole, full pixel covariances (cov_px)", t_cov, p_cov),
            ("scanrig closed form + Gauss-Newton + exact covariance", t_gn, p_gn)]
    for name, t, p in rows:
        print(f"| {name} | {n / t / 1e6:.3f} | {t_cv / t:.2f} | {_rms(p - p_true) * 1e3:.4f} | "
              f"{_rms(p - p_true) / rms_gn:.4f} |")
    print(f"| scanrig closed form, opencv5 distortion (Newton undistortion) | {n / t_dist / 1e6:.3f} | "
          f"{t_cv / t_dist:.2f} | | |")


def bench_uncertainty(n_frames):
    rng = np.random.default_rng(2)
    rig = ring_rig()
    p_true = points_in_cube(rng, n_frames)
    table, _ = spot_traces(rig, p_true, rng, SIGMA_PX)
    _, _, matches = reconstruct_spots(rig, table, frame_order(table), sigma_floor_px=0.0)
    ok = matches.info.ok
    e = matches.p_world[ok] - p_true[ok]
    z = np.linalg.solve(np.linalg.cholesky(matches.info.cov[ok]), e[..., None])[..., 0]
    along = np.linalg.norm(e, axis=1) / matches.info.sigma[ok]
    print(f"\n## 2. Uncertainty over a synthetic spot scan ({ok.sum()} points, {SIGMA_PX} px noise)\n")
    print("| statistic | value | acceptance |")
    print("|---|---|---|")
    print(f"| std of whitened error components | {z.std():.3f} | 0.8-1.25 |")
    print(f"| RMS of |error| / sigma (largest axis) | {np.sqrt(np.mean(along**2)):.3f} | <= sqrt(3) |")


def reflection_figures(azimuths, n_frames, seed=3):
    """Issue 6 figures of spot matching on synthetic traces (30 % reflections, 10 % occlusions).

    The frame list is every frame the synthetic scan took (``f0000``...), as ``scanrig detect``
    records it in ``frames_done``: a frame in which no camera found a candidate is not in the
    traces table, and building the list from the table alone would shift every later frame index
    against the truth (it once made the 3-camera RMS read 82 mm).

    Returns
    -------
    dict
        ``with_reflection`` (fraction of frames), ``rejected`` (fraction of reflection candidates
        that no output point uses), ``matched``/``ambiguous`` (frames), ``points``, ``rms_m`` and
        ``beyond_1mm`` (over the output points, as the acceptance states), ``recall`` (output
        points within 1 mm over all frames), ``err_m`` and ``sigma_m`` per output point.
    """
    rng = np.random.default_rng(seed)
    rig = ring_rig(azimuths)
    p_true = points_in_cube(rng, n_frames)
    table, truth = spot_traces(rig, p_true, rng, SIGMA_PX, reflection_rate=0.3, occlusion_rate=0.1)
    frames = [f"f{k:04d}" for k in range(n_frames)]  # frame index k <-> p_true[k]
    cloud, summary, matches = reconstruct_spots(rig, table, frames)
    n_refl, rejected = reflection_outcome(rig, frames, truth, matches)
    err = np.linalg.norm(cloud.p_world - p_true[cloud.frame], axis=1)
    return dict(with_reflection=len({f for (_, f), r in truth.items() if r.any()}) / n_frames,
                rejected=rejected / n_refl, matched=summary["frames_matched"],
                ambiguous=summary["frames_ambiguous"], points=len(cloud),
                rms_m=float(np.sqrt(np.mean(err**2))), beyond_1mm=float(np.mean(err > 1e-3)),
                recall=float(np.sum(err <= 1e-3) / n_frames), err_m=err, sigma_m=cloud.sigma)


def bench_reflections(n_frames):
    print(f"\n## 3. Reflection rejection, synthetic traces ({n_frames} frames, 30 % reflections, 10 % occlusions)\n")
    print("| cameras | frames with a reflection | reflections rejected | matched | ambiguous | RMS (mm) "
          "| beyond 1 mm (of output points) | frames with a point within 1 mm |")
    print("|---|---|---|---|---|---|---|---|")
    for azimuths in ((-40.0, 0.0, 40.0), (-60.0, -20.0, 20.0, 60.0)):
        r = reflection_figures(azimuths, n_frames)
        print(f"| {len(azimuths)} | {100 * r['with_reflection']:.0f} % | {100 * r['rejected']:.1f} % | "
              f"{r['matched']} | {r['ambiguous']} | {1e3 * r['rms_m']:.3f} | {100 * r['beyond_1mm']:.2f} % "
              f"| {100 * r['recall']:.1f} % |")


def bench_stripes(n_frames):
    """Stripe mode on synthetic traces: points per frame (spot mode gives 1), accuracy, reflections."""
    rig = ring_rig(height_m=0.6)
    print(f"\n## 3b. Stripes, synthetic traces ({n_frames} frames, 0.2 px, wavy surface)\n")
    print("| case | points/frame | multi-view | single-view (plane) | RMS height error (mm) | beyond 1 mm |")
    print("|---|---|---|---|---|---|")
    offsets = np.linspace(-0.1, 0.1, n_frames)
    for label, kwargs in (("clean", {}), ("reflection in cam1 (rank 1, 15 px)", {"reflection_camera": 1}),
                          ("y > 0.08 m seen by cam0 only", {"hidden_y_m": 0.08})):
        table = stripe_traces(rig, offsets, np.random.default_rng(4), 0.2, **kwargs)
        # this rig's points have a sigma of 0.1-0.2 mm: its accuracy target is 0.2 mm, not the default 0.1
        cloud, summary = reconstruct_stripes(rig, table, frame_order(table), np.random.default_rng(0),
                                             max_sigma_m=2e-4)
        dz = cloud.p_world[:, 2] - height_field(cloud.p_world[:, 0], cloud.p_world[:, 1])
        print(f"| {label} | {len(cloud) / n_frames:.0f} | {summary['points_multi_view']} | "
              f"{summary['points_single_view']} | {1e3 * np.sqrt(np.mean(dz**2)):.4f} | "
              f"{100 * np.mean(np.abs(dz) > 1e-3):.2f} % |")


def build_session(root, scene, cameras, frames, seed, shots):
    """Simulate, calibrate (scanrig's own calibration, not the true rig) and detect a spot session.

    Skipped when ``root/traces.parquet`` exists. Runs the CLI verbs, as a user would.
    """
    import subprocess

    root = Path(root)
    if (root / "traces.parquet").is_file():
        return root
    run = [sys.executable, "-m", "scanrig"]
    steps = [["simulate", str(root), "--scene", scene, "--cameras", str(cameras), "--mode", "spot",
              "--frames", str(frames), "--shots", str(shots), "--seed", str(seed)],
             ["calibrate", str(root), "--no-plots"],
             ["detect", str(root), "--mode", "spot", "--workers", "2"]]
    for step in steps:
        subprocess.run(run + step, check=True, stdout=subprocess.DEVNULL)
    return root


def _secondary_frames(truth_dir):
    """Frame stems with at least one true secondary hit (``truth/frames.csv``)."""
    with open(truth_dir / "frames.csv", newline="") as f:
        return {row["frame"] for row in csv.DictReader(f) if row["kind"] == "secondary"}


def _reflection_candidates(rig_true, table, frames, truth_dir, kind="secondary"):
    """``(frame_index, camera_index, rank)`` of candidates at a true secondary hit's projection
    (``kind="primary"``: at the beam's own hit)."""
    hits = {}
    with open(truth_dir / "frames.csv", newline="") as f:
        for row in csv.DictReader(f):
            if row["kind"] == kind:
                hits.setdefault(row["frame"], []).append([float(row[k]) for k in "xyz"])
    out = set()
    cams = table.column("camera").to_pylist()
    stems = table.column("frame").to_pylist()
    uv = np.c_[table.column("u").to_numpy(), table.column("v").to_numpy()]
    ranks = table.column("rank").to_numpy()
    for r, (cam, stem) in enumerate(zip(cams, stems)):
        if stem not in hits:
            continue
        q = rig_true[cam].project(np.array(hits[stem]))
        if np.nanmin(np.linalg.norm(q - uv[r], axis=1)) < REFLECTION_MATCH_PX:
            out.add((frames.index(stem), rig_true.names.index(cam), int(ranks[r])))
    return out


def bench_sessions(sessions):
    if not sessions:
        print("\n## 4. End to end on the simulator: no --session given (skipped)\n")
        return
    print("\n## 4. End to end on simulator sessions\n")
    print("| session | rig | cut | cameras | frames | points | matched (spot) / with plane (stripe) "
          "| single-view (stripe) | ambiguous | frames w/ secondary hit (truth) | frames w/ reflection candidate "
          "| reflections rejected | reflections used (frames with the point within 1 mm of the surface) "
          "| RMS (mm) | p99 (mm) | beyond 1 mm | RMS d/sigma |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for root in sessions:
        root = Path(root)
        truth_dir = root / "truth"
        rig_true = load_rig(truth_dir / "rig.toml")
        table, meta = read_traces(root / "traces.parquet")
        frames = frame_order(table, meta)
        surface = load_truth_surface(truth_dir)
        if (truth_dir / "frames.csv").is_file():
            reflections = _reflection_candidates(rig_true, table, frames, truth_dir)
            # a reflection landing within ~1 mm of the spot (a concave corner, a weld) is one blob
            # with it: the candidate is also at the beam's own hit, and using it is right
            merged = reflections & _reflection_candidates(rig_true, table, frames, truth_dir, kind="primary")
            frames_refl = len({f for f, _, _ in reflections})
            frames_refl = f"{frames_refl} ({100 * frames_refl / len(frames):.0f} %)"
            frames_sec = len(_secondary_frames(truth_dir) & set(frames))
            frames_sec = f"{frames_sec} ({100 * frames_sec / len(frames):.0f} %)"
        else:  # a session without the hits' truth (scanrig demo's): no reflection figures
            reflections, merged, frames_refl, frames_sec = set(), set(), "n/a", "n/a"
        rigs = [("true", truth_dir / "rig.toml")] + ([("calibrated", root / "rig.toml")]
                                                     if (root / "rig.toml").is_file() else [])
        mode = table.column("kind")[0].as_py()
        for label, rig_path in rigs:
            rig = load_rig(rig_path)
            alignment = None if label == "true" else rig_alignment(rig, rig_true)
            if mode == "spot":
                cloud, summary, matches = reconstruct_spots(rig, table, frames)
                # a reflection counts as rejected when no written point uses it; choice holds candidate
                # positions in rank order, and detect's ranks are 0..n-1 per camera and frame
                written = matches.status == FrameStatus.MATCHED  # ambiguous frames write no point
                used = {(f, i, k) for f, i, k in reflections if written[f] and matches.choice[f, i] == k}
                n_rej, n_sep = len(reflections) - len(used), len(reflections - merged)
                rejected = (f"{n_rej}/{len(reflections)} ({100 * n_rej / max(1, len(reflections)):.1f} %); "
                            f"{n_rej}/{n_sep} ({100 * n_rej / max(1, n_sep):.1f} %) of the "
                            f"{n_sep} apart from the spot")
                # A used reflection apart from the spot made the frame's point on the surface it lit
                # (the beam's own hit was seen by fewer than two cameras): on the true surface, but
                # attributed to the wrong beam.
                apart = sorted({f for f, _, _ in used - merged})
                p_used = matches.p_world[apart]
                if alignment is not None and len(p_used):
                    p_used = alignment.apply(p_used)
                on_surface = (f"{len(used & merged)} merged with the spot; {len(used - merged)} apart in "
                              f"{len(apart)} frames, {int(np.sum(surface(p_used) <= 1e-3)) if apart else 0} "
                              "of them within 1 mm")
                rows = [("-", cloud, summary["frames_matched"], "-", summary["frames_ambiguous"], rejected)]
            else:
                # the default precision cut (0.1 mm across the stripe) and none
                rows = []
                for cut, max_sigma_m in (("0.1 mm", None), ("none", np.inf)):
                    cloud, summary = reconstruct_stripes(rig, table, frames, np.random.default_rng(0),
                                                         max_sigma_m=max_sigma_m)
                    rows.append((cut, cloud, summary["frames_with_plane"], summary["points_single_view"], "-",
                                 f"{summary['pairs_off_plane']} pairs off plane"))
                on_surface = "-"
            for cut, cloud, matched, single, ambiguous, rejected in rows:
                p_world = cloud.p_world if alignment is None else alignment.apply(cloud.p_world)
                d = surface(p_world)
                stats = distance_statistics(d)
                print(f"| {root.name} ({mode}) | {label} | {cut} | {len(rig)} | {len(frames)} | {len(cloud)} | "
                      f"{matched} | {single} | {ambiguous} | {frames_sec} | {frames_refl} | {rejected} | "
                      f"{on_surface} | {stats['rms_m'] * 1e3:.4f} | {stats['p99_m'] * 1e3:.4f} | "
                      f"{100 * stats['fraction_beyond']:.2f} % | {np.sqrt(np.mean((d / cloud.sigma) ** 2)):.2f}* |")
        _stereo_baseline(root, rig_true, surface)
    print("\n*RMS of (distance to the surface / sigma of the largest axis); the distance is one "
          "component of the error, so ~1 or less is honest.")


def _stereo_baseline(root, rig, surface):
    """SGM on the laser-off frames of neighbouring cameras, evaluated like the active points."""
    session = Session(root)
    images = {}
    for name in rig.names:
        path = session.dark_path(name)
        if path is not None:
            images[name] = read_image(path)
    try:
        p = stereo_rig_points(rig, images, depth_range_m=(0.6, 1.6))
    except InputError as exc:
        print(f"| {root.name} | SGM stereo baseline (true rig) | not applicable: {exc} |")
        return
    stats = distance_statistics(surface(p[:: max(1, len(p) // 50000)]))
    print(f"| {root.name} | SGM stereo baseline (true rig, dark frames) | {len(rig)} | 1 | {len(p)} | | | | | "
          f"{stats['rms_m'] * 1e3:.4f} | {stats['p99_m'] * 1e3:.4f} | {100 * stats['fraction_beyond']:.2f} % | |")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (under a minute)")
    parser.add_argument("--session", action="append", default=[], help="simulated session folder (repeatable)")
    parser.add_argument("--shiny", metavar="DIR", help="also evaluate the shiny-part session(s) in DIR "
                        "(simulated, calibrated and detected there when missing, ~4 min each)")
    parser.add_argument("--shiny-seed", type=int, action="append", help="seed of a shiny session (repeatable; default 7)")
    args = parser.parse_args(argv)
    n, repeats, frames = (200_000, 2, 300) if args.quick else (1_000_000, 3, 2000)
    print(f"# bench_reconstruct ({'quick' if args.quick else 'full'}), numpy {np.__version__}")
    bench_triangulation(n, repeats)
    bench_uncertainty(frames)
    bench_reflections(frames)
    bench_stripes(3 if args.quick else 20)
    sessions = list(args.session)
    if args.shiny:
        for seed in args.shiny_seed or [7]:
            sessions.append(build_session(Path(args.shiny) / f"shiny4-seed{seed}", seed=seed, **SHINY))
    bench_sessions(sessions)


if __name__ == "__main__":
    main()

"""Over-exposed red stripes in colour frames, rendered and real: accuracy, honesty of sigma, speed.

Run ``python benchmarks/bench_colour_stripes.py`` (about a minute; ``--seeds N`` for more).

Rendered set (``tests/laser/colour_synth.py``): white paper with 40 printed black dots, a red line
laser 8 × past full scale on paper, crosstalk 7 % / 5 % into green / blue, a sub-surface halo
(30 % of the light, 3 px), Bayer demosaicing and JPEG quality 90 (4:2:0); 640 × 480 for accuracy,
1920 × 1080 for speed. Next to scanrig, in the same run, the baseline of Horus and FabScan: per
row, the 7-pixel centre of gravity of ``red − (green + blue) / 2`` (laser-off frame subtracted
where there is one) around the row's maximum. Then the same set with one frame of the pair at
another exposure (automatic exposure or white balance), next to the laser-off frame subtracted as
it is, and with flicker bands (a rolling shutter under a flickering lamp) on one frame of the pair,
matched row by row, as a whole, or subtracted as it is. The speed section also times the candidate
search alone (``max_per_line=0``: nothing is fitted).

Real frames (``tests/data/ciclop-laser-stripes``, CC BY-SA 4.0): a Ciclop scanner's webcam, a red
line laser on a white bust; rank 0 is counted on the stripe when within 6 px of the row's
strongest red difference (laser on − off), on the rows where that difference exceeds 60 DN. Then
the chessboard's ``-x`` pair: two lasers on a flat board, so each laser's rank <= 1 points inside
the board, undistorted with the data set's intrinsics, lie on a straight line
(``tests/laser/ciclop_board.py``).
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from contextlib import nullcontext  # noqa: E402
from pathlib import Path  # noqa: E402
from unittest import mock  # noqa: E402

import cv2  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.data_paths import real_data  # noqa: E402
from tests.laser import ciclop_board as board  # noqa: E402
from tests.laser.colour_synth import exposed, stripe_frames  # noqa: E402

from scanrig.io.session import read_image  # noqa: E402
from scanrig.laser import exposure as frame_exposure  # noqa: E402
from scanrig.laser import image  # noqa: E402
from scanrig.laser.bright_scene import BrightSceneWarning  # noqa: E402
from scanrig.laser.stripes import detect_stripe  # noqa: E402

EDGE_ROWS = 8
#: Rows of the running mean that shows how the Ciclop board's laser lines bend.
SMOOTH_ROWS = 15
COG_HALF = 3


def cog_rows(on: np.ndarray, off: np.ndarray | None) -> np.ndarray:
    """Baseline: 7-pixel centre of gravity of red minus the mean of green and blue, per row."""
    f = on.astype(np.float64)
    signal = f[:, :, 0] - 0.5 * (f[:, :, 1] + f[:, :, 2])
    if off is not None:
        g = off.astype(np.float64)
        signal -= g[:, :, 0] - 0.5 * (g[:, :, 1] + g[:, :, 2])
    peak = np.clip(np.argmax(signal, axis=1), COG_HALF, signal.shape[1] - 1 - COG_HALF)
    idx = peak[:, None] + np.arange(-COG_HALF, COG_HALF + 1)
    w = np.clip(np.take_along_axis(signal, idx, axis=1), 0, None)
    return (w * idx).sum(axis=1) / np.maximum(w.sum(axis=1), 1e-12)


def rank0_by_row(table, n_rows: int):
    """Rank-0 row-scanned centre, its sigma and clip flag per row (NaN / False where none)."""
    u, v, line, rank, sigma, clipped = (table[k].to_numpy() for k in
                                        ("u", "v", "line", "rank", "sigma_px", "saturated"))
    best = (rank == 0) & (v == line)
    centre, sig, sat = np.full(n_rows, np.nan), np.full(n_rows, np.nan), np.zeros(n_rows, bool)
    centre[line[best]], sig[line[best]], sat[line[best]] = u[best], sigma[best], clipped[best]
    return centre, sig, sat


def nearest_by_row(table, truth: np.ndarray) -> np.ndarray:
    """Per row, the distance from the true centre to the nearest row-scanned candidate of any rank
    (inf where none): the share within 0.5 px is the most any ranking of these candidates reaches."""
    u, v, line = (table[k].to_numpy() for k in ("u", "v", "line"))
    rows = v == line
    nearest = np.full(truth.size, np.inf)
    np.minimum.at(nearest, line[rows], np.abs(u[rows] - truth[line[rows]]))
    return nearest


def accuracy(seeds) -> None:
    print("Rendered over-exposed red stripes, 640x480 (per laser-off setting, pooled over seeds)")
    print(f"{'dark':6}{'rows':>7}{'<0.5px':>8}{'median':>8}{'COG7 <0.5':>11}{'COG7 med':>10}"
          f"{'z clipped':>11}{'n':>6}{'z unclipped':>13}{'n':>5}{'cands':>7}{'any <0.5px':>12}")
    for use_dark in (False, True):
        err, base, z_sat, z_un, cands, any_rank = [], [], [], [], [], []
        for seed in seeds:
            on, off, truth = stripe_frames(np.random.default_rng(seed))
            dark = off if use_dark else None
            t = detect_stripe(on, color="red", dark=dark)
            centre, sig, sat = rank0_by_row(t, on.shape[0])
            rows = slice(EDGE_ROWS, on.shape[0] - EDGE_ROWS)
            e = (centre - truth)[rows]
            good = np.abs(e) < 0.5
            z = e / sig[rows]
            z_sat.append(z[good & sat[rows]])
            z_un.append(z[good & ~sat[rows]])
            err.append(e)
            base.append((cog_rows(on, dark) - truth)[rows])
            cands.append(len(t))
            any_rank.append(nearest_by_row(t, truth)[rows] < 0.5)
        e, b = np.concatenate(err), np.concatenate(base)
        zs, zu = np.concatenate(z_sat), np.concatenate(z_un)

        def spread(z):
            return 1.4826 * np.median(np.abs(z))

        print(f"{'yes' if use_dark else 'no':6}{e.size:7d}{np.mean(np.abs(e) < 0.5):8.3f}"
              f"{np.nanmedian(np.abs(e)):8.3f}{np.mean(np.abs(b) < 0.5):11.3f}{np.median(np.abs(b)):10.3f}"
              f"{spread(zs):11.2f}{zs.size:6d}{spread(zu):13.2f}{zu.size:5d}{np.mean(cands):7.0f}"
              f"{np.mean(np.concatenate(any_rank)):12.3f}")
    print("  z = robust spread (MAD) of error / reported sigma over rows within 0.5 px; target 0.7-1.4")
    print("  any <0.5px = rows with a candidate of any rank within 0.5 px: the most a ranking can reach")


#: Gains of one frame of the pair (DN times the gain, clipped pixels still clipped).
GAINS = (0.7, 0.8, 0.9, 1.1, 1.25, 1.5)


def exposure(seeds) -> None:
    """Rank 0 within 0.5 px with one frame of the rendered pair at another exposure, the laser-off
    frame matched (scanrig) and subtracted as it is (the baseline: exposure matching switched off)."""
    frames = [stripe_frames(np.random.default_rng(seed)) for seed in seeds]

    def share(on_gain, off_gain):
        rows = slice(EDGE_ROWS, -EDGE_ROWS)
        within = [np.abs(rank0_by_row(detect_stripe(exposed(on, on_gain), color="red", dark=exposed(off, off_gain)),
                                      on.shape[0])[0] - truth)[rows] < 0.5 for on, off, truth in frames]
        return np.mean(np.concatenate(within))

    print(f"\nOne frame of the rendered pair at another exposure (640x480, seeds {seeds.start}-{seeds.stop - 1}): "
          f"rank 0 within 0.5 px, {share(1.0, 1.0):.3f} at one exposure")
    print(f"  {'gain of':34}" + "".join(f"{'x' + format(g, 'g'):>8}" for g in GAINS))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", BrightSceneWarning)  # the laser-on frame at x 1.5 clips the paper
        for which in ("laser-off frame", "laser-on frame"):
            for label, matched in (("matched", True), ("subtracted as it is", False)):
                with mock.patch.object(image, "exposure_matched", image.exposure_matched if matched
                                       else lambda frame, dark: dark):
                    shares = [share(*((1.0, g) if which == "laser-off frame" else (g, 1.0))) for g in GAINS]
                print(f"  {which + ', ' + label:34}" + "".join(f"{x:8.3f}" for x in shares))


#: Amplitudes of the flicker bands (each row's gain 1 + a sin(2π row / FLICKER_PERIOD_ROWS + 0.7)).
FLICKER_AMPLITUDES = (0.05, 0.1, 0.2, 0.3)
FLICKER_PERIOD_ROWS = 300.0


def flicker(seeds) -> None:
    """Rank 0 within 0.5 px with flicker bands on one frame of the rendered pair: the laser-off frame
    matched row by row (scanrig), matched as a whole (row gains switched off) and subtracted as it is."""
    frames = [stripe_frames(np.random.default_rng(seed)) for seed in seeds]

    def share(which, amplitude):
        rows = slice(EDGE_ROWS, -EDGE_ROWS)
        within = []
        for on, off, truth in frames:
            bands = (1.0 + amplitude * np.sin(2.0 * np.pi * np.arange(on.shape[0]) / FLICKER_PERIOD_ROWS + 0.7))
            bands = bands[:, None, None]
            on, off = (on, exposed(off, bands)) if which == "laser-off frame" else (exposed(on, bands), off)
            within.append(np.abs(rank0_by_row(detect_stripe(on, color="red", dark=off), on.shape[0])[0] - truth)[rows]
                          < 0.5)
        return np.mean(np.concatenate(within))

    print(f"\nFlicker bands on one frame of the rendered pair (640x480, seeds {seeds.start}-{seeds.stop - 1}, "
          f"period {FLICKER_PERIOD_ROWS:g} rows): rank 0 within 0.5 px")
    print(f"  {'bands on, laser-off frame':44}" + "".join(f"{'+-' + format(a, 'g'):>8}" for a in FLICKER_AMPLITUDES))
    variants = {"matched row by row": {},
                "matched as a whole": {"row_gains": lambda frame, dark: None},
                "subtracted as it is": {"exposure_matched": lambda frame, dark: dark}}
    for which in ("laser-off frame", "laser-on frame"):
        for label, patches in variants.items():
            module = image if "exposure_matched" in patches else frame_exposure
            with mock.patch.multiple(module, **patches) if patches else nullcontext():
                shares = [share(which, a) for a in FLICKER_AMPLITUDES]
            print(f"  {which + ', ' + label:44}" + "".join(f"{x:8.3f}" for x in shares))


def speed(reps: int) -> None:
    cv2.setNumThreads(1)
    on, off, _ = stripe_frames(np.random.default_rng(0), shape=(1080, 1920))
    print(f"\nSpeed, one 1920x1080 RGB frame, one core, ms: median wall under the current load, median and "
          f"best CPU of {reps} runs, and the median CPU over the COG7 baseline's in this run "
          f"(load {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs)")
    print("  (candidates alone: detect_stripe with max_per_line=0, every step but the fit)")
    print(f"  {'task':36}{'wall':>9}{'cpu':>9}{'best':>9}{'x COG7':>9}")
    runs = {"detect_stripe": lambda: detect_stripe(on, color="red"),
            "detect_stripe, laser-off frame": lambda: detect_stripe(on, color="red", dark=off),
            "candidates alone": lambda: detect_stripe(on, color="red", max_per_line=0),
            "candidates alone, laser-off frame": lambda: detect_stripe(on, color="red", dark=off, max_per_line=0),
            "COG7 baseline": lambda: cog_rows(on, None)}
    measured = {}
    for name, fn in runs.items():
        fn()
        wall, cpu = [], []
        for _ in range(reps):
            w0, c0 = time.perf_counter(), time.process_time()
            fn()
            cpu.append(1e3 * (time.process_time() - c0))
            wall.append(1e3 * (time.perf_counter() - w0))
        measured[name] = np.median(wall), np.median(cpu), min(cpu)
    for name, (wall, cpu, best) in measured.items():
        print(f"  {name:36}{wall:9.1f}{cpu:9.1f}{best:9.1f}{cpu / measured['COG7 baseline'][1]:9.1f}")


def ciclop() -> None:
    folder = real_data("ciclop-laser-stripes") / "laser_on_object"
    on, off = read_image(folder / "laser.png"), read_image(folder / "laser_background.png")
    added = on[:, :, 0].astype(int) - off[:, :, 0]
    rows = np.arange(on.shape[0])
    rows = rows[(added.max(axis=1) > 60) & (rows > 40) & (rows < 1115)]
    reference = np.argmax(added[rows], axis=1)
    print(f"\nReal Ciclop frame (960x1280, red laser on a white bust), {rows.size} rows with the laser on it")
    for use_dark in (False, True):
        dark = off if use_dark else None
        t0 = time.process_time()
        t = detect_stripe(on, color="red", dark=dark)
        ms = 1e3 * (time.process_time() - t0)
        centre, _, _ = rank0_by_row(t, on.shape[0])
        share = np.mean(np.abs(centre[rows] - reference) < 6.0)
        base = np.mean(np.abs(cog_rows(on, dark)[rows] - reference) < 6.0)
        print(f"  laser-off frame {'yes' if use_dark else 'no ':3}: rank 0 on the stripe {share:.4f}, "
              f"COG7 {base:.4f}; {len(t)} candidates, {ms:.0f} ms CPU")
    ciclop_board()


def ciclop_board() -> None:
    on, off = board.frames()
    outline = board.board_outline()
    print("\nReal Ciclop board (the -x pair, two lasers, a glint beside the left one), rank <= 1 points inside "
          "the board, undistorted: RMS from each laser's straight line")
    print(f"  {'saturation_level':18}{'laser':>7}{'n':>5}{'RMS':>7}{'<1px n':>8}{'RMS':>7}{'sigma':>7}"
          f"{'glint rows <1.5px':>19}{'offset':>8}{'15-row RMS':>12}")
    for level in (None, "auto"):
        lines = board.board_lines(detect_stripe(on, color="red", dark=off, saturation_level=level), outline)
        by_row = []
        for name, (p, sigma, row) in zip(("left", "right"), lines):
            residual = board.line_residuals(p)
            near = np.abs(residual) < 1.0
            glint = (row >= board.GLINT_ROWS[0]) & (row <= board.GLINT_ROWS[1])
            off_glint = board.line_residuals(p, ~glint)[glint]
            by_row.append(row_residuals(p, residual))
            smoothed = np.convolve(by_row[-1][1], np.ones(SMOOTH_ROWS) / SMOOTH_ROWS, "valid")
            print(f"  {level!s:18}{name:>7}{len(p):5d}{np.sqrt(np.mean(residual**2)):7.3f}{near.sum():8d}"
                  f"{np.sqrt(np.mean(board.line_residuals(p[near]) ** 2)):7.3f}{np.sqrt(np.mean(sigma[near] ** 2)):7.3f}"
                  f"{np.mean(np.abs(off_glint) < 1.5):19.2f}{np.median(off_glint):+8.2f}"
                  f"{np.sqrt(np.mean(smoothed**2)):12.3f}")
        (left_v, left_r), (right_v, right_r) = by_row
        rows = np.arange(max(left_v[0], right_v[0]), min(left_v[-1], right_v[-1]))
        print(f"  {'':18}the two lines' residuals, correlation row by row: "
              f"{np.corrcoef(np.interp(rows, left_v, left_r), np.interp(rows, right_v, right_r))[0, 1]:.2f}")
    print("  <1px: the points within 1 px of the line, their RMS about their own line and their reported sigma (RMS);")
    print("  glint rows (569-638): share within 1.5 px of the line through the other rows, and their median offset;")
    print(f"  15-row RMS: the residuals of the points within 1.5 px, {SMOOTH_ROWS}-row running mean (a bend of the light")
    print("  itself; centre noise averages out)")


def row_residuals(points: np.ndarray, residual: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The residuals of the points within 1.5 px of their line, ``(v (n,), residual (n,))`` px, in
    order of their undistorted row ``v``, one value per whole row."""
    near = np.abs(residual) < 1.5
    v, r = points[near, 1], residual[near]
    order = np.argsort(v)
    rows = np.arange(np.ceil(v.min()), np.floor(v.max()) + 1)
    return rows, np.interp(rows, v[order], r[order])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=6, help="rendered frames per laser-off setting")
    parser.add_argument("--reps", type=int, default=5)
    args = parser.parse_args()
    accuracy(range(args.seeds))
    exposure(range(args.seeds))
    flicker(range(args.seeds))
    speed(args.reps)
    ciclop()


if __name__ == "__main__":
    main()

"""Print-ready SVG files at true scale (user units = millimetres) for every target.

Print at 100 % ("actual size", no "fit to page"), then measure one square or the spacing with a
ruler: the calibration uses the lengths of ``target.toml``, so a printer that scales by 1 %
makes every length 1 % wrong. Each file carries a 50 mm scale bar outside the pattern, for the
check.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from scanrig.io.atomic import write_text_atomic
from scanrig.targets.boards import Board, CharucoBoard, ChessBoard, CircleGridBoard
from scanrig.targets.target import CUBE_FACES, Target

#: Length of the printed scale bar, millimetres.
SCALE_BAR_MM = 50.0
#: Space below a board for the label and the scale bar, millimetres.
FOOTER_MM = 14.0
MM_PER_M = 1000.0


def board_shapes(board: Board, x0_mm: float = 0.0, y0_mm: float = 0.0) -> list[str]:
    """SVG elements drawing ``board`` with its top-left corner at ``(x0_mm, y0_mm)``.

    The white paper itself is not drawn; black ink is drawn as rectangles (squares, marker
    cells) or circles, in millimetres.
    """
    if isinstance(board, CircleGridBoard):
        r = 0.5 * board.diameter_m * MM_PER_M
        return [f'<circle cx="{x0_mm + x * MM_PER_M:.4f}" cy="{y0_mm + y * MM_PER_M:.4f}" r="{r:.4f}"/>'
                for x, y in board.points_local]
    if not isinstance(board, (ChessBoard, CharucoBoard)):
        raise TypeError(f"no print layout for {type(board).__name__}")
    cols, rows = board.squares
    i, j = np.meshgrid(np.arange(cols), np.arange(rows))
    black = (i + j) % 2 == (0 if board.top_left_black else 1)
    s = board.square_m * MM_PER_M
    m = board.margin_m * MM_PER_M
    rects = [(m + a * s, m + b * s, s, s) for a, b in zip(i[black], j[black])]
    if isinstance(board, CharucoBoard):
        corners, bits = board.marker_layout
        n_cells = bits.shape[1]
        cell = board.marker_m * MM_PER_M / n_cells
        for (mx, my), marker in zip(corners * MM_PER_M, bits):
            cy, cx = np.nonzero(marker == 0)
            rects += [(mx + a * cell, my + b * cell, cell, cell) for a, b in zip(cx, cy)]
    return [f'<rect x="{x0_mm + x:.4f}" y="{y0_mm + y:.4f}" width="{w:.4f}" height="{h:.4f}"/>'
            for x, y, w, h in rects]


def _svg(width_mm: float, height_mm: float, body: list[str]) -> str:
    return (
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width_mm:.4f}mm" height="{height_mm:.4f}mm" '
        f'viewBox="0 0 {width_mm:.4f} {height_mm:.4f}" shape-rendering="crispEdges">\n'
        f'<rect x="0" y="0" width="{width_mm:.4f}" height="{height_mm:.4f}" fill="white"/>\n'
        + "\n".join(body) + "\n</svg>\n"
    )


def _footer(label: str, x_mm: float, y_mm: float) -> list[str]:
    """A text label and a 50 mm scale bar starting at ``(x_mm, y_mm)``."""
    return [
        f'<text x="{x_mm:.3f}" y="{y_mm + 4:.3f}" font-family="sans-serif" font-size="3.5" fill="black">'
        f'{label}</text>',
        f'<rect x="{x_mm:.3f}" y="{y_mm + 7:.3f}" width="{SCALE_BAR_MM}" height="1.5" fill="black"/>',
        f'<text x="{x_mm + SCALE_BAR_MM + 2:.3f}" y="{y_mm + 8.5:.3f}" font-family="sans-serif" '
        f'font-size="3" fill="black">{SCALE_BAR_MM:g} mm: check at print</text>',
    ]


def board_svg(board: Board, label: str) -> str:
    """One board as a whole SVG document at true scale, with a label and a scale bar below."""
    w, h = (v * MM_PER_M for v in board.size_m)
    body = ['<g fill="black">', *board_shapes(board), "</g>"]
    body += _footer(label, 0.0, h + 1.0)
    return _svg(max(w, SCALE_BAR_MM + 45.0), h + FOOTER_MM, body)


def cube_net_svg(target: Target) -> str:
    """The cube's faces as a cross-shaped net (4 sides in a row, +z above and -z below ``+x``).

    Each face is labelled in its margin with its board name and outward normal; glue each print
    on the cube face it names, print "up" towards +z for side faces (see :func:`scanrig.targets.cube`).
    """
    edge = target.spec["edge_m"] * MM_PER_M
    slots = {"+x": (0, 1), "+y": (1, 1), "-x": (2, 1), "-y": (3, 1), "+z": (0, 0), "-z": (0, 2)}
    names = list(CUBE_FACES)
    body = []
    for board in target.boards:
        face = names[int(board.name.removeprefix("face"))]
        col, row = slots[face]
        x0, y0 = col * edge, row * edge
        body += ['<g fill="black">', *board_shapes(board, x0, y0), "</g>"]
        body.append(f'<rect x="{x0:.4f}" y="{y0:.4f}" width="{edge:.4f}" height="{edge:.4f}" fill="none" '
                    'stroke="#999" stroke-width="0.2"/>')
        body.append(f'<text x="{x0 + 1.5:.3f}" y="{y0 + 3.5:.3f}" font-family="sans-serif" font-size="2.5" '
                    f'fill="#666">{board.name} ({face})</text>')
    body += _footer(f"scanrig cube, edge {edge:g} mm", 0.0, 3 * edge + 1.0)
    return _svg(4 * edge, 3 * edge + FOOTER_MM, body)


def write_print_files(target: Target, out_dir: str | Path) -> list[Path]:
    """Write print-ready SVGs for a target; returns the files written.

    Planar targets give ``board.svg``. The cube gives one ``face<k>.svg`` per face (each fits an
    A4 sheet for edges up to 0.2 m) and ``cube_net.svg`` with all faces.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    names = list(CUBE_FACES)
    for board in target.boards:
        if target.kind == "cube":
            face = names[int(board.name.removeprefix("face"))]
            label = f"scanrig cube {board.name}: face {face} (outward normal); print top towards +z on side faces"
        else:
            label = f"scanrig {target.kind}: " + ", ".join(
                f"{k} = {v}" for k, v in target.spec.items() if k != "kind")
        path = out / f"{board.name}.svg"
        write_text_atomic(path, board_svg(board, label))
        written.append(path)
    if target.kind == "cube":
        path = out / "cube_net.svg"
        write_text_atomic(path, cube_net_svg(target))
        written.append(path)
    return written

"""The session folder (DESIGN.md §4): the contract between rigs, simulator, CLI and tests.

::

    SESSION/
      session.toml                 optional: camera order, laser colour and mode, clip level, target file
      target.toml                  the calibration target
      calibration/<camera>/<shot>.<ext>              (<ext>: IMAGE_SUFFIXES)
      calibration_intrinsic/<camera>/<image>.<ext>   optional: each camera's own intrinsic calibration
      scan/<camera>/<frame>.<ext>                    (+ optional dark.<ext>, the laser-off frame, and
                                                     dark/<frame>.<ext>, a frame's own)
      rig.toml, traces.parquet, points.ply, surface.ply, mesh.ply, report.html
      truth/                       simulator only
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError
from scanrig.io.toml_fields import check_keys, read_toml

#: Images read (8- or 16-bit, grey or colour): PNG, TIFF, BMP and the PNM family (PGM, PPM) as
#: machine-vision cameras' tools save them, lossless; JPEG and WebP.
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp", ".dib", ".pgm", ".ppm", ".pnm", ".webp")
#: Image files that cameras and their tools save but scanrig does not read (1-bit, palette,
#: floating-point and camera raw files): in a camera folder they are an error naming them, not
#: frames silently left out.
UNREAD_IMAGE_SUFFIXES = (".pbm", ".pfm", ".jp2", ".gif", ".exr", ".hdr", ".avif", ".heic", ".dng", ".raw", ".nef",
                         ".cr2", ".arw")
#: Stem of the optional laser-off frame in ``scan/<camera>/``.
DARK_STEM = "dark"
STAGES = ("calibration", "calibration_intrinsic", "scan")
_SESSION_KEYS = ("cameras", "laser_color", "laser_mode", "saturation_level", "target", "seed", "created_by",
                 "notes")


def natural_key(text: str):
    """Sort key that orders embedded numbers numerically: ``cam2`` before ``cam10``."""
    # isdecimal, not isdigit: "²" is a digit that int() refuses; \d matches exactly the decimals
    return [int(part) if part.isdecimal() else part for part in re.split(r"(\d+)", text)]


@dataclass(frozen=True)
class Session:
    """A session folder on disk.

    Parameters
    ----------
    root : Path
        The folder.
    """

    root: Path

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root))
        if not self.root.is_dir():
            raise FileFormatError(self.root, "session folder not found")

    # --- files ----------------------------------------------------------------------------
    @property
    def rig_path(self) -> Path:
        return self.root / "rig.toml"

    @property
    def target_path(self) -> Path:
        return self.root / self.settings().get("target", "target.toml")

    @property
    def traces_path(self) -> Path:
        return self.root / "traces.parquet"

    @property
    def points_path(self) -> Path:
        return self.root / "points.ply"

    @property
    def truth_dir(self) -> Path:
        return self.root / "truth"

    def settings(self) -> dict:
        """The parsed ``session.toml`` (empty when absent)."""
        path = self.root / "session.toml"
        if not path.exists():
            return {}
        doc = read_toml(path)
        check_keys(doc, _SESSION_KEYS, (), path, "top level")
        cams = doc.get("cameras")
        if cams is not None and (not isinstance(cams, list) or not all(isinstance(c, str) for c in cams)):
            raise FileFormatError(path, f"cameras must be a list of folder names, got {cams!r}")
        if cams is not None and len(set(cams)) != len(cams):
            duplicated = sorted({c for c in cams if cams.count(c) > 1})
            raise FileFormatError(path, f"cameras must be unique, duplicated: {duplicated}")
        level = doc.get("saturation_level", "auto")
        if not (level == "auto" or (isinstance(level, (int, float)) and not isinstance(level, bool) and level > 0)):
            raise FileFormatError(path, f"saturation_level must be a positive number of DN or \"auto\", got {level!r}")
        return doc

    # --- cameras and images --------------------------------------------------------------------
    def camera_names(self, stage: str) -> list[str]:
        """Camera names of a stage folder, in ``session.toml`` order or natural order.

        Parameters
        ----------
        stage : {"calibration", "calibration_intrinsic", "scan"}

        Raises
        ------
        FileFormatError
            If the stage folder is missing or empty, or ``session.toml`` names a camera whose
            folder is missing.
        """
        folder = self._stage_dir(stage)
        present = sorted((p.name for p in folder.iterdir() if p.is_dir()), key=natural_key)
        if not present:
            raise FileFormatError(folder, "no camera folders found")
        order = self.settings().get("cameras")
        if order is None:
            return present
        missing = [c for c in order if c not in present]
        if missing:
            raise FileFormatError(folder, f"camera folders {missing} named in session.toml are missing")
        return list(order)

    def image_paths(self, stage: str, camera: str) -> dict[str, Path]:
        """``stem -> path`` of a camera's images in a stage, in natural order (dark frame excluded).

        Raises
        ------
        FileFormatError
            If the camera folder is missing, or as :func:`images_by_stem`.
        """
        folder = self._stage_dir(stage) / camera
        if not folder.is_dir():
            raise FileFormatError(folder, "camera folder not found")
        return images_by_stem(folder, skip_stem=DARK_STEM)

    def dark_path(self, camera: str) -> Path | None:
        """The laser-off frame of a camera in ``scan/``, if there is one."""
        for suffix in IMAGE_SUFFIXES:
            p = self.root / "scan" / camera / f"{DARK_STEM}{suffix}"
            if p.exists():
                return p
        return None

    def frame_dark_paths(self, camera: str) -> dict[str, Path]:
        """``stem -> path`` of the laser-off frames that scan frames of a camera have of their own,
        ``scan/<camera>/dark/<stem>.<ext>`` (a turntable's object moves, so each step takes one);
        empty without that folder.

        Raises
        ------
        FileFormatError
            As :func:`images_by_stem`.
        """
        folder = self.root / "scan" / camera / DARK_STEM
        return images_by_stem(folder) if folder.is_dir() else {}

    def frames(self, stage: str, cameras: list[str] | None = None) -> dict[str, dict[str, Path]]:
        """``stem -> {camera: path}`` for every stem seen by any camera, in natural order.

        A stem missing in some cameras simply lacks those keys (a camera had no view or dropped
        the frame); callers decide whether that is acceptable.
        """
        cameras = cameras or self.camera_names(stage)
        by_stem: dict[str, dict[str, Path]] = {}
        for cam in cameras:
            for stem, path in self.image_paths(stage, cam).items():
                by_stem.setdefault(stem, {})[cam] = path
        return {s: by_stem[s] for s in sorted(by_stem, key=natural_key)}

    def _stage_dir(self, stage: str) -> Path:
        if stage not in STAGES:
            raise InputError(f"stage must be one of {STAGES}, got {stage!r}")
        folder = self.root / stage
        if not folder.is_dir():
            raise FileFormatError(folder, f"{stage} folder not found in session")
        return folder


def images_by_stem(folder: Path, skip_stem: str | None = None) -> dict[str, Path]:
    """``stem -> path`` of the images in a folder, in natural order.

    Parameters
    ----------
    folder : Path
        A camera's folder of images.
    skip_stem : str, optional
        Leave out the images of this stem (the laser-off frame, ``DARK_STEM``).

    Raises
    ------
    FileFormatError
        If two images share a stem, or an image is in a format scanrig does not read
        (``UNREAD_IMAGE_SUFFIXES``, e.g. ``.bmp``): it would be a frame silently left out.
    """
    paths = {}
    for p in sorted(folder.iterdir(), key=lambda p: natural_key(p.name)):
        if p.suffix.lower() in UNREAD_IMAGE_SUFFIXES:
            raise FileFormatError(p, f"{p.suffix} images are not read; save the frames as "
                                     f"{', '.join(IMAGE_SUFFIXES)} (PNG, TIFF, BMP and PNM are lossless)")
        if p.suffix.lower() in IMAGE_SUFFIXES and p.stem != skip_stem:
            if p.stem in paths:
                raise FileFormatError(p, f"two images share the stem {p.stem!r} (also {paths[p.stem].name})")
            paths[p.stem] = p
    return paths


def session_file(path: str | Path, name: str, producer: str) -> Path:
    """A product file given as itself or as the session folder that holds it.

    Parameters
    ----------
    path : str or Path
        The file, or a session folder.
    name : str
        The product's file name in a session folder (``points.ply``, ``rig.toml`` ...).
    producer : str
        The verb that writes it, named in the error (``scanrig reconstruct``).

    Returns
    -------
    Path
        ``path`` itself, or ``path / name`` for a folder.

    Raises
    ------
    FileFormatError
        If ``path`` is a folder without ``name``.
    """
    path = Path(path)
    if not path.is_dir():
        return path
    if not (path / name).is_file():
        raise FileFormatError(path, f"session folder holds no {name} ({producer} writes it)")
    return path / name


#: Names a one-line message lists before "and N more" (existing entries, kept files).
LISTED_ENTRIES = 4


def check_new_session(root: str | Path, verb: str, force: bool, *, can_force: bool = True
                      ) -> dict[Path, tuple[int, int]]:
    """Refuse to write a new session into a folder that already holds something, unless forced.

    Parameters
    ----------
    root : str or Path
        The session folder to create (it may exist and be empty).
    verb : str
        The command that writes it, for the message (``scanrig simulate``).
    force : bool
        Write anyway (the command then replaces the files it writes and deletes nothing).
    can_force : bool
        The command has a ``--force`` option, which the refusal then suggests.

    Returns
    -------
    dict
        ``path -> (inode, mtime_ns)`` of every file already below ``root`` (empty for a new
        folder); :func:`kept_files` tells afterwards which of them the command did not replace.

    Raises
    ------
    InputError
        If ``root`` is a file, or a non-empty folder and ``force`` is false; nothing is written.
    """
    root = Path(root)
    if root.exists() and not root.is_dir():
        raise InputError(f"{root}: output session folder is an existing file")
    if not root.is_dir():
        return {}
    entries = sorted((p.name + "/" if p.is_dir() else p.name for p in root.iterdir()), key=natural_key)
    if entries and not force:
        hint = ", or --force to replace the files it writes (nothing is deleted)" if can_force else ""
        raise InputError(f"{root} is not empty (it holds {first_names(entries)}) and {verb} would overwrite files "
                         f"there; give a new or empty folder{hint}")
    return {p: _stamp(p) for p in root.rglob("*") if p.is_file()}


def first_names(names: list[str], limit: int = LISTED_ENTRIES) -> str:
    """``"a, b, c, d and 3 more"``: the first ``limit`` names for a one-line message."""
    more = f" and {len(names) - limit} more" if len(names) > limit else ""
    return ", ".join(names[:limit]) + more


def kept_files(before: dict[Path, tuple[int, int]]) -> list[Path]:
    """The files of :func:`check_new_session`'s snapshot that are still there, unchanged."""
    return sorted((p for p, stamp in before.items() if p.is_file() and _stamp(p) == stamp),
                  key=lambda p: natural_key(str(p)))


def _stamp(path: Path) -> tuple[int, int]:
    """Inode and modification time: an atomic replacement (a new file renamed over) changes both."""
    st = path.stat()
    return st.st_ino, st.st_mtime_ns


#: PNG files start with this signature; the byte at ``_PNG_COLOUR_TYPE_AT`` (in the IHDR chunk that
#: must follow it) is the colour type, 4 for grey with alpha, which OpenCV decodes as BGRA.
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_COLOUR_TYPE_AT = 25
_PNG_GREY_ALPHA = 4


def read_image(path: str | Path) -> np.ndarray:
    """Read an 8- or 16-bit image as stored (grey ``(H, W)`` or colour ``(H, W, 3)`` in RGB order).

    An alpha channel is dropped: a grey PNG with alpha is grey, not three equal colour channels
    (in which a colour laser's signal, its channel minus the others, would be 0).

    Raises
    ------
    FileFormatError
        If the file is missing, unreadable, truncated, empty, or not 8/16-bit.
    """
    import cv2

    path = Path(path)
    if not path.is_file():
        raise FileFormatError(path, "image file not found")
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise FileFormatError(path, "image file is empty")
    img = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise FileFormatError(path, "cannot decode image (unreadable or truncated file)")
    if img.dtype not in (np.uint8, np.uint16):
        raise FileFormatError(path, f"expected an 8- or 16-bit image, got {img.dtype}")
    if img.ndim == 3:
        if img.shape[2] == 4 and _is_grey_alpha_png(data):
            return np.ascontiguousarray(img[:, :, 0])
        if img.shape[2] == 4:
            img = img[:, :, :3]
        elif img.shape[2] != 3:
            raise FileFormatError(path, f"expected 1 or 3 channels, got {img.shape[2]}")
        img = np.ascontiguousarray(img[:, :, ::-1])
    return img


def _is_grey_alpha_png(data: np.ndarray) -> bool:
    """Whether the file's bytes ``data`` (uint8) are a PNG of colour type grey with alpha."""
    return (data[:len(_PNG_SIGNATURE)].tobytes() == _PNG_SIGNATURE and data.size > _PNG_COLOUR_TYPE_AT
            and data[_PNG_COLOUR_TYPE_AT] == _PNG_GREY_ALPHA)


def describe_image(shape: tuple[int, ...], dtype) -> str:
    """``"1280x1024 8-bit grey"``: an image's size, bit depth and kind, for messages."""
    h, w = shape[:2]
    bits = 8 if str(dtype) == "uint8" else 16
    return f"{w}x{h} {bits}-bit {'colour' if len(shape) == 3 else 'grey'}"


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Write an 8- or 16-bit grey or RGB image atomically (format from the suffix; PNG is lossless)."""
    import cv2

    from scanrig.io.atomic import write_bytes_atomic

    path = Path(path)
    if image.dtype not in (np.uint8, np.uint16):
        raise InputError(f"image for {path} must be uint8 or uint16, got {image.dtype}")
    if image.ndim == 3:
        image = image[:, :, ::-1]
    ok, buf = cv2.imencode(path.suffix, image)
    if not ok:
        raise FileFormatError(path, f"cannot encode an image as {path.suffix!r}")
    write_bytes_atomic(path, buf.tobytes())

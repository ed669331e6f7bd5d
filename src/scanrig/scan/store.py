"""The scan's session store: frames, commanded beams and planner state, written as they arrive.

Layout inside the session folder (``docs/scanning.md``)::

    scan/<camera>/f000123.png     one image per camera and frame (atomic write)
    scan/<camera>/dark.png        the laser-off frame, grabbed before the first beam
    scan/beams.csv                the commanded beam of every frame (a convenience table)
    scan/manifest.jsonl           the append-only log that defines what the scan contains

The manifest is a JSON-lines log; each line is ``<crc32 hex> <json>`` and is fsynced before the
next step starts. A crash can only leave a torn *last* line, which fails its checksum and is
dropped (and truncated away) on resume. A frame exists once its ``frame`` record is in the log:
images written before a crash but not yet logged are simply captured again under the same stem,
so nothing is lost or duplicated. ``beams.csv`` is rewritten from the manifest on resume.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from scanrig.errors import FileFormatError, InputError, ScanrigError
from scanrig.io.atomic import write_text_atomic
from scanrig.io.session import DARK_STEM, write_image
from scanrig.scan.protocol import Beam

FORMAT_VERSION = 1
MANIFEST_NAME = "manifest.jsonl"
BEAMS_NAME = "beams.csv"
BEAMS_HEADER = "frame,pass,origin_x_m,origin_y_m,origin_z_m,dir_x,dir_y,dir_z,fan_x,fan_y,fan_z\n"
IMAGE_SUFFIX = ".png"
RESUME_HINT = "everything captured so far is saved; fix the cause and run `scanrig scan SESSION --resume`"


class StoreError(ScanrigError):
    """Writing the scan to disk failed (e.g. the disk is full); what was logged before stays valid."""


def frame_stem(index: int) -> str:
    """Frame stem of frame ``index``: ``f000123``."""
    return f"f{index:06d}"


@dataclass
class PassRecord:
    """One planner pass: the beams it planned and the generator state around the planning.

    Attributes
    ----------
    number : int
        Pass number, 0 for the uniform pass.
    beams : list of Beam
        Beams planned by the pass, in capture order.
    aims_m : (n_beams, 3) float array
        World points the beams were aimed at (metres); the planner's memory of what it tried.
    rng_after : dict
        ``rng.bit_generator.state`` right after planning; the next pass plans from it.
    first_frame : int
        Frame index of the pass's first beam.
    """

    number: int
    beams: list[Beam]
    aims_m: np.ndarray
    rng_after: dict
    first_frame: int


@dataclass
class ScanState:
    """What the manifest says about a scan."""

    config: dict
    cameras: list[str]
    passes: list[PassRecord] = field(default_factory=list)
    frames: list[str] = field(default_factory=list)
    finished: str | None = None
    has_dark: bool = False

    @property
    def beams(self) -> list[Beam]:
        """Beams of every pass in capture order (captured or still to capture)."""
        return [b for p in self.passes for b in p.beams]

    @property
    def aims_m(self) -> np.ndarray:
        """(n_beams, 3) aim points of every planned beam, metres."""
        return np.concatenate([p.aims_m for p in self.passes]) if self.passes else np.empty((0, 3))

    @property
    def pending(self) -> list[Beam]:
        """Planned beams not yet captured."""
        return self.beams[len(self.frames):]


class ScanStore:
    """Read and append the scan part of a session folder.

    Use :meth:`create` for a new scan and :meth:`open` to resume one.
    """

    def __init__(self, root: Path, state: ScanState):
        self.root = Path(root)
        self.scan_dir = self.root / "scan"
        self.manifest_path = self.scan_dir / MANIFEST_NAME
        self.beams_path = self.scan_dir / BEAMS_NAME
        self.state = state

    # --- opening ------------------------------------------------------------------------------
    @classmethod
    def create(cls, root: str | Path, cameras: list[str], config: dict) -> ScanStore:
        """Start a new scan in ``root`` (created if needed).

        Parameters
        ----------
        root : str or Path
            Session folder.
        cameras : list of str
            Camera names in rig order.
        config : dict
            JSON-serialisable scan settings (seed, planner settings, budget); ``--resume`` reuses them.

        Raises
        ------
        InputError
            If the session already holds a scan manifest or scan images.
        """
        root = Path(root)
        manifest = root / "scan" / MANIFEST_NAME
        if manifest.exists():
            raise InputError(f"{manifest} already exists: pass --resume to continue that scan, "
                             "or use a new session folder")
        if (root / "scan").is_dir() and any(p.is_dir() for p in (root / "scan").iterdir()):
            raise InputError(f"{root / 'scan'} already holds camera folders but no manifest; use a new session folder")
        store = cls(root, ScanState(dict(config), list(cameras)))
        try:
            for cam in cameras:
                (store.scan_dir / cam).mkdir(parents=True, exist_ok=True)
            if not (root / "session.toml").exists():
                write_text_atomic(root / "session.toml", _session_toml(cameras, config))
            store._append({"kind": "start", "format_version": FORMAT_VERSION, "cameras": list(cameras),
                           "config": config})
            write_text_atomic(store.beams_path, BEAMS_HEADER)
        except OSError as exc:
            raise StoreError(f"cannot start the scan in {root}: {exc}") from exc
        return store

    @classmethod
    def open(cls, root: str | Path) -> ScanStore:
        """Open an interrupted (or finished) scan for ``--resume``.

        A torn last manifest line is truncated away, temporary files left by a killed atomic write
        are removed, and ``beams.csv`` is rebuilt from the manifest.

        Raises
        ------
        FileFormatError
            If there is no manifest, or a line other than the last is corrupt.
        """
        manifest = _existing_manifest(root)
        records, valid_bytes = _read_log(manifest)
        state = _replay(records, manifest)
        store = cls(Path(root), state)
        try:
            if valid_bytes < manifest.stat().st_size:
                os.truncate(manifest, valid_bytes)
            for tmp in store.scan_dir.glob("*/.*.tmp"):
                tmp.unlink()
            write_text_atomic(store.beams_path, BEAMS_HEADER + "".join(
                _beam_line(stem, p.number, b) for p in state.passes
                for stem, b in zip(state.frames[p.first_frame:], p.beams)))
        except OSError as exc:
            raise StoreError(f"cannot repair {manifest}: {exc}") from exc
        return store

    # --- appending ------------------------------------------------------------------------------
    def add_pass(self, number: int, beams: list[Beam], aims_m: np.ndarray, rng_after: dict) -> PassRecord:
        """Log a planned pass before any of its beams is captured."""
        record = PassRecord(number, list(beams), np.asarray(aims_m, dtype=np.float64).reshape(-1, 3),
                            rng_after, len(self.state.beams))
        self._append({"kind": "pass", "pass": number, "first_frame": record.first_frame,
                      "beams": [_beam_json(b) for b in beams], "aims_m": record.aims_m.tolist(),
                      "rng_after": rng_after})
        self.state.passes.append(record)
        return record

    def add_frame(self, images: dict[str, np.ndarray]) -> str:
        """Write the images of the next pending beam, then log the frame; returns its stem.

        Raises
        ------
        StoreError
            If a file cannot be written (full disk, permissions); earlier frames stay valid.
        RigError
            Never here; the loop checks the grabbed images before calling.
        """
        index = len(self.state.frames)
        beam = self.state.beams[index]
        pass_no = next(p.number for p in reversed(self.state.passes) if p.first_frame <= index)
        stem = frame_stem(index)
        files = {cam: f"{cam}/{stem}{IMAGE_SUFFIX}" for cam in self.state.cameras}
        for cam in self.state.cameras:
            try:
                write_image(self.scan_dir / files[cam], images[cam])
            except OSError as exc:
                raise StoreError(f"cannot write frame {stem} of camera {cam!r}: {exc}; {RESUME_HINT}") from exc
        self._append({"kind": "frame", "index": index, "frame": stem, "pass": pass_no,
                      "beam": _beam_json(beam), "files": files})
        self.state.frames.append(stem)
        try:
            with open(self.beams_path, "a", encoding="utf-8") as f:
                f.write(_beam_line(stem, pass_no, beam))
        except OSError as exc:
            raise StoreError(f"cannot append to {self.beams_path}: {exc}; {RESUME_HINT}") from exc
        return stem

    def add_dark(self, images: dict[str, np.ndarray]) -> None:
        """Write the laser-off frame of every camera (``scan/<camera>/dark.png``), then log it."""
        for cam in self.state.cameras:
            try:
                write_image(self.dark_paths()[cam], images[cam])
            except OSError as exc:
                raise StoreError(f"cannot write the dark frame of camera {cam!r}: {exc}; {RESUME_HINT}") from exc
        self._append({"kind": "dark", "files": {cam: f"{cam}/{DARK_STEM}{IMAGE_SUFFIX}" for cam in self.state.cameras}})
        self.state.has_dark = True

    def dark_paths(self) -> dict[str, Path]:
        """``{camera: path}`` of the laser-off frames (written by :meth:`add_dark`)."""
        return {cam: self.scan_dir / cam / f"{DARK_STEM}{IMAGE_SUFFIX}" for cam in self.state.cameras}

    def finish(self, reason: str) -> None:
        """Log the end of the scan and why it ended."""
        self._append({"kind": "done", "n_frames": len(self.state.frames), "reason": reason})
        self.state.finished = reason

    def frame_paths(self) -> dict[str, dict[str, Path]]:
        """``stem -> {camera: image path}`` of every logged frame, in capture order."""
        return {stem: {cam: self.scan_dir / cam / f"{stem}{IMAGE_SUFFIX}" for cam in self.state.cameras}
                for stem in self.state.frames}

    def _append(self, record: dict) -> None:
        payload = json.dumps(record, separators=(",", ":"), allow_nan=False)
        line = f"{zlib.crc32(payload.encode()):08x} {payload}\n"
        try:
            with open(self.manifest_path, "a", encoding="utf-8") as f:
                f.write(line)
                f.flush()
                os.fsync(f.fileno())
        except OSError as exc:
            raise StoreError(f"cannot append to {self.manifest_path}: {exc}; {RESUME_HINT}") from exc


# --- manifest parsing -----------------------------------------------------------------------------
def read_state(root: str | Path) -> ScanState:
    """What the manifest of a session says, read-only (a torn last line is ignored, not repaired).

    Raises
    ------
    FileFormatError
        If there is no manifest, or a line other than the last is corrupt.
    """
    manifest = _existing_manifest(root)
    return _replay(_read_log(manifest)[0], manifest)


def _existing_manifest(root: str | Path) -> Path:
    """Path of a session's scan manifest; FileFormatError if there is none."""
    manifest = Path(root) / "scan" / MANIFEST_NAME
    if not manifest.is_file():
        raise FileFormatError(manifest, "no scan manifest to resume (start the scan without --resume)")
    return manifest


def _read_log(path: Path) -> tuple[list[dict], int]:
    """Records of a manifest and the byte length of its valid prefix (a torn last line is dropped)."""
    data = path.read_bytes()
    lines = data.split(b"\n")
    records, offset = [], 0
    for number, raw in enumerate(lines[:-1], start=1):  # the piece after the last "\n" is torn or empty
        record = _parse_line(raw)
        if record is None:
            if number == len(lines) - 1:
                break
            raise FileFormatError(path, f"line {number} is corrupt (checksum mismatch) and is not the last line")
        records.append(record)
        offset += len(raw) + 1
    return records, offset


def _parse_line(raw: bytes) -> dict | None:
    crc, _, payload = raw.partition(b" ")
    try:
        if int(crc, 16) != zlib.crc32(payload) or len(crc) != 8:
            return None
        return json.loads(payload)
    except ValueError:
        return None


def _replay(records: list[dict], path: Path) -> ScanState:
    if not records or not isinstance(records[0], dict) or records[0].get("kind") != "start":
        raise FileFormatError(path, "the first record must be the scan's start record (a scan killed while "
                                    "starting: delete the scan folder and start again)")
    start = records[0]
    if start.get("format_version") != FORMAT_VERSION:
        raise FileFormatError(path, f"format_version must be {FORMAT_VERSION}, got {start.get('format_version')!r}")
    i = 1
    try:
        state = ScanState(dict(start["config"]), [str(c) for c in start["cameras"]])
        for i, rec in enumerate(records[1:], start=2):
            kind = rec.get("kind")
            if kind == "pass":
                state.passes.append(PassRecord(rec["pass"], [_beam_from_json(b) for b in rec["beams"]],
                                               np.asarray(rec["aims_m"], dtype=np.float64).reshape(-1, 3),
                                               rec["rng_after"], rec["first_frame"]))
            elif kind == "frame":
                if rec["index"] != len(state.frames) or rec["index"] >= len(state.beams):
                    raise FileFormatError(path, f"record {i}: frame {rec['frame']} is out of sequence")
                state.frames.append(rec["frame"])
            elif kind == "done":
                state.finished = rec["reason"]
            elif kind == "dark":
                state.has_dark = True
            else:
                raise FileFormatError(path, f"record {i}: unknown kind {kind!r}")
    except FileFormatError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        # A checksummed record of another shape: written by another scanrig version or edited by hand.
        raise FileFormatError(path, f"record {i}: malformed record ({type(exc).__name__}: {exc})") from None
    return state


def _beam_json(beam: Beam) -> dict:
    return {"origin": beam.origin.tolist(), "direction": beam.direction.tolist(),
            "fan_axis": None if beam.fan_axis is None else beam.fan_axis.tolist()}


def _beam_from_json(d: dict) -> Beam:
    return Beam(np.array(d["origin"]), np.array(d["direction"]),
                None if d["fan_axis"] is None else np.array(d["fan_axis"]))


def _beam_line(stem: str, pass_no: int, beam: Beam) -> str:
    return ",".join([stem, str(pass_no), *(repr(x) for x in beam.as_row())]) + "\n"


def _session_toml(cameras: list[str], config: dict) -> str:
    import tomli_w

    doc = {"cameras": list(cameras), "created_by": "scanrig scan"}
    if "seed" in config:
        doc["seed"] = config["seed"]
    return tomli_w.dumps(doc)

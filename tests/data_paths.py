"""Paths of the real data shipped with the tests: ``tests/data/<set>/``, each set with its own licence."""

from pathlib import Path

#: ``tests/data``: real images and detections from real rigs, one folder per data set, each with
#: its PROVENANCE.md (source and licence) beside the files.
DATA_DIR = Path(__file__).resolve().parent / "data"


def real_data(name: str) -> Path:
    """The folder of one real data set in ``tests/data``.

    Parameters
    ----------
    name : str
        The data set's folder name, e.g. ``"opencv-stereo-9x6"``.

    Returns
    -------
    Path
        ``tests/data/<name>``.

    Raises
    ------
    FileNotFoundError
        If the folder is missing: the data ship with the repository, so a missing set is an
        error, never a reason to skip.
    """
    path = DATA_DIR / name
    if not path.is_dir():
        raise FileNotFoundError(f"real data set {path} is missing; it ships with the repository")
    return path

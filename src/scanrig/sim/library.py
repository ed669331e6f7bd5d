"""Named scenes shipped with scanrig (``src/scanrig/sim/scenes/*.toml``), and scene lookup."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from scanrig.errors import InputError
from scanrig.sim.scene import Scene
from scanrig.sim.scene_file import load_scene_file


def scene_names() -> list[str]:
    """Names of the built-in scenes."""
    folder = resources.files("scanrig.sim") / "scenes"
    return sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))


def scene_path(name: str) -> Path:
    """Path of a built-in scene file."""
    if name not in scene_names():
        raise InputError(f"unknown scene {name!r}; built-in scenes are {scene_names()} (or give a .toml file)")
    return Path(str(resources.files("scanrig.sim") / "scenes" / f"{name}.toml"))


def load_scene(name_or_path: str | Path) -> Scene:
    """A built-in scene by name, or a scene file by path (anything ending in ``.toml``).

    Raises
    ------
    InputError
        For an unknown name; :class:`~scanrig.errors.FileFormatError` for a bad file.
    """
    text = str(name_or_path)
    if text.endswith(".toml") or Path(text).is_file():
        return load_scene_file(text)
    return load_scene_file(scene_path(text))

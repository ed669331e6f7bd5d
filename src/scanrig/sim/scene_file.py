"""Scene files (TOML): objects, materials, lighting, cameras, laser and sensor.

Format (lengths in metres, angles in degrees; every section but ``[[objects]]`` is optional and
takes the fields of the matching class: :class:`~scanrig.sim.scene.Lighting`,
:class:`~scanrig.sim.rigs.RigSpec`, :class:`~scanrig.sim.laser.LaserSpec`,
:class:`~scanrig.sim.sensor.Sensor`, :class:`~scanrig.sim.materials.Material`)::

    name = "default"
    center_m = [0.0, 0.0, 0.1]        # region of interest: cameras aim here, the laser covers it
    radius_m = 0.25

    [lighting]
    ambient_W_m2 = 40.0

    [rig]
    distance_m = 1.0

    [laser]
    head_m = [0.3, -0.75, 0.75]

    [sensor]
    bit_depth = 12

    [camera]                          # optional: colour cameras (scanrig.sim.colour.ColourResponse)
    color = true
    laser_rgb = [1.0, 0.06, 0.04]
    halo_fraction = 0.3
    laser_overexposure = 8.0          # sets the laser's powers (scanrig.sim.laser_exposure)

    [calibration]                     # optional
    board_flex_m = [0.001, 0.0]       # calibration target's boards bent by (c_x, c_y), metres

    [materials.steel]
    kind = "metal"                    # matte | dark | metal
    specular = 0.6
    roughness_rad = 0.03

    [[objects]]
    name = "beam"
    shape = "ibeam_joint"             # plane sphere box cylinder torus stepped_block ibeam_joint freeform mesh
    material = "steel"
    position_m = [0.1, 0.0, 0.0]
    rotation_deg = [0.0, 0.0, 30.0]   # extrinsic x, y, z
    length_m = 0.25                   # shape parameters: the arguments of scanrig.sim.primitives.<shape>

    [[objects]]
    name = "part"
    shape = "mesh"
    file = "part.stl"                 # STL, PLY or OBJ, relative to this file
    scale = 0.001                     # file units to metres
    material = "paint"
"""

from __future__ import annotations

import dataclasses
import inspect
import math
from collections.abc import Mapping
from pathlib import Path

from scanrig.errors import FileFormatError, InputError
from scanrig.io.toml_fields import check_keys, read_toml
from scanrig.sim import primitives
from scanrig.sim.colour import ColourResponse, check_sensor
from scanrig.sim.laser import LaserSpec
from scanrig.sim.laser_exposure import overexposed_laser
from scanrig.sim.materials import Material
from scanrig.sim.rigs import RigSpec
from scanrig.sim.scene import Lighting, Scene, SceneObject, place
from scanrig.sim.sensor import Sensor

_TOP = ("name", "description", "center_m", "radius_m", "lighting", "rig", "laser", "sensor", "camera", "materials",
        "objects", "calibration")
_SECTIONS = {"lighting": Lighting, "rig": RigSpec, "laser": LaserSpec, "sensor": Sensor}
_OBJECT_COMMON = ("name", "shape", "material", "position_m", "rotation_deg")
#: Keys of ``[camera]`` besides the fields of ColourResponse.
_CAMERA_OWN = ("color", "laser_overexposure")


def load_scene_file(path: str | Path) -> Scene:
    """Read a scene file.

    Parameters
    ----------
    path : str or Path
        A TOML scene file (format in the module docstring).

    Returns
    -------
    Scene

    Raises
    ------
    FileFormatError
        Naming the file and the section or field at fault.
    """
    path = Path(path)
    doc = read_toml(path)
    check_keys(doc, _TOP, ("objects",), path, "top level")
    sections = {key: _section(doc.get(key, {}), cls, path, f"[{key}]") for key, cls in _SECTIONS.items()}
    colour = _camera(doc.get("camera", {}), doc.get("laser", {}), sections, doc.get("center_m", (0.0, 0.0, 0.1)), path)
    materials = {}
    mat_tables = doc.get("materials", {})
    if not isinstance(mat_tables, Mapping):
        raise FileFormatError(path, "[materials]: expected tables [materials.<name>]")
    for name, table in mat_tables.items():
        materials[name] = _section(table, Material, path, f"[materials.{name}]", name=name)
    tables = doc["objects"]
    if not isinstance(tables, list) or not tables:
        raise FileFormatError(path, "objects must be a non-empty array of [[objects]] tables")
    objects = [_object(t, i, materials, path) for i, t in enumerate(tables, start=1)]
    board_flex_m = _board_flex(doc.get("calibration", {}), path)
    try:
        return Scene(
            name=str(doc.get("name", path.stem)),
            objects=tuple(objects),
            center_m=tuple(doc.get("center_m", (0.0, 0.0, 0.1))),
            radius_m=float(doc.get("radius_m", 0.25)),
            colour=colour,
            board_flex_m=board_flex_m,
            **sections,
        )
    except (InputError, TypeError, ValueError) as exc:
        raise FileFormatError(path, f"top level: {exc}") from None


def _section(table, cls, path: Path, where: str, **fixed):
    if not isinstance(table, Mapping):
        raise FileFormatError(path, f"{where}: expected a table")
    allowed = [f.name for f in dataclasses.fields(cls) if f.init and not f.name.startswith("_") and f.name not in fixed]
    check_keys(table, allowed, (), path, where)
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
    try:
        return cls(**fixed, **values)
    except (InputError, TypeError, ValueError) as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None


def _board_flex(table, path: Path) -> tuple[float, float]:
    """``board_flex_m`` of the ``[calibration]`` table: two finite numbers, metres ((0, 0) if absent)."""
    where = "[calibration]"
    if not isinstance(table, Mapping):
        raise FileFormatError(path, f"{where}: expected a table")
    check_keys(table, ("board_flex_m",), (), path, where)
    value = table.get("board_flex_m", [0.0, 0.0])
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) for v in value)):
        raise FileFormatError(path, f"{where}: board_flex_m must be two numbers (c_x, c_y) in metres, got {value!r}")
    return float(value[0]), float(value[1])


def _camera(table, laser_table, sections: dict, center_m, path: Path) -> ColourResponse | None:
    """The ``[camera]`` table: the colour response (None for grey cameras). ``laser_overexposure``
    replaces ``sections["laser"]`` by the laser of that nominal exposure."""
    where = "[camera]"
    if not isinstance(table, Mapping):
        raise FileFormatError(path, f"{where}: expected a table")
    colour_keys = [f.name for f in dataclasses.fields(ColourResponse)]
    check_keys(table, (*_CAMERA_OWN, *colour_keys), (), path, where)
    color = table.get("color", False)
    if not isinstance(color, bool):
        raise FileFormatError(path, f"{where}: color must be true or false, got {color!r}")
    if "laser_overexposure" in table:
        fixed = [k for k in ("power_W", "stripe_power_W") if k in laser_table]
        if fixed:
            raise FileFormatError(path, f"{where}: laser_overexposure sets the laser's powers; "
                                        f"remove {fixed[0]} from [laser]")
        try:
            sections["laser"] = overexposed_laser(sections["laser"], sections["sensor"], sections["rig"], center_m,
                                                  table["laser_overexposure"])
        except (InputError, TypeError, ValueError) as exc:
            raise FileFormatError(path, f"{where}: {exc}") from None
    response = {k: v for k, v in table.items() if k in colour_keys}
    if not color:
        if response:
            raise FileFormatError(path, f"{where}: {sorted(response)[0]} applies to colour cameras; set color = true")
        return None
    colour = _section(response, ColourResponse, path, where)
    try:
        check_sensor(colour, sections["sensor"])
    except InputError as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None
    return colour


def _object(table, index: int, materials: dict, path: Path) -> SceneObject:
    where = f"[[objects]] #{index}"
    if not isinstance(table, Mapping):
        raise FileFormatError(path, f"{where}: expected a table")
    for key in ("name", "shape", "material"):
        if key not in table:
            raise FileFormatError(path, f"{where}: missing field {key!r}")
    where = f"{where} ({table['name']!r})"
    shape = table["shape"]
    if shape == "mesh":
        params = ("file", "scale")
        required = ("file",)
    elif isinstance(shape, str) and shape in primitives.SHAPES:
        sig = inspect.signature(primitives.SHAPES[shape]).parameters.values()
        params = tuple(p.name for p in sig)
        required = tuple(p.name for p in sig if p.default is inspect.Parameter.empty)
    else:
        raise FileFormatError(path, f"{where}: shape must be one of {sorted(primitives.SHAPES) + ['mesh']}, got {shape!r}")
    check_keys(table, _OBJECT_COMMON + params, required, path, where)
    if not isinstance(table["material"], str) or table["material"] not in materials:
        raise FileFormatError(path, f"{where}: material {table['material']!r} is not defined; "
                                    f"defined: {sorted(materials)}")
    args = {k: table[k] for k in params if k in table}
    try:
        if shape == "mesh":
            mesh = _load_mesh(path.parent / args["file"], float(args.get("scale", 1.0)))
        else:
            mesh = primitives.SHAPES[shape](**args)
        mesh = place(mesh, table.get("position_m", (0.0, 0.0, 0.0)), table.get("rotation_deg", (0.0, 0.0, 0.0)))
    except FileFormatError:
        raise
    except (InputError, TypeError, ValueError) as exc:
        raise FileFormatError(path, f"{where}: {exc}") from None
    return SceneObject(str(table["name"]), mesh, materials[table["material"]])


def _load_mesh(file: Path, scale: float):
    """A triangle mesh from STL, PLY or OBJ, scaled to metres."""
    import trimesh

    if file.suffix.lower() not in (".stl", ".ply", ".obj"):
        raise FileFormatError(file, "mesh file must be .stl, .ply or .obj")
    if not file.is_file():
        raise FileFormatError(file, "mesh file not found")
    try:
        mesh = trimesh.load_mesh(file, force="mesh")
    except Exception as exc:  # noqa: BLE001 - trimesh raises many types for broken files
        raise FileFormatError(file, f"cannot read mesh: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise FileFormatError(file, "mesh file holds no triangles")
    if not scale > 0:
        raise InputError(f"mesh scale must be positive, got {scale!r}")
    mesh.apply_scale(scale)
    return mesh

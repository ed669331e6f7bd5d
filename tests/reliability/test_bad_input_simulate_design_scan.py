"""Bad-input matrix, part: `scanrig simulate`, `scanrig design`, `scanrig scan` (scene and design TOML,
options) and typer's own usage errors on every verb."""

import re

import pytest

from tests.reliability.cases import no_change, write_text
from tests.reliability.matrix import assert_fails_cleanly, snapshot

SPHERE = ('name = "x"\n[materials.paint]\nkind = "matte"\n'
          '[[objects]]\nname = "ball"\nshape = "sphere"\nradius_m = 0.1\nmaterial = "paint"\n')
SIMULATE = ["simulate", "{s}/out", "--scene", "{s}/scene.toml", "--frames", "1", "--no-calibration"]
DESIGN = ["design", "--out", "{s}/design", "--scene", "sphere", "--spec", "{s}/spec.toml"]


def scene(text):
    return write_text("scene.toml", text)


def malformed_manifest(s):
    """A checksummed start record without its camera list (another version, or a hand edit)."""
    from tests.reliability.test_fuzz_readers import manifest_line

    (s / "sc" / "scan").mkdir(parents=True)
    (s / "sc" / "scan" / "manifest.jsonl").write_bytes(
        manifest_line({"kind": "start", "format_version": 1, "config": {"seed": 0}}))


#: case -> (setup on the good session, argv with {s} for the session, expected error line)
CASES = {
    "unknown built-in scene": (no_change, ["simulate", "{s}/out", "--scene", "nope"],
                               r"unknown scene 'nope'; built-in scenes are \[.*'default'.*\] \(or give a .toml file\)"),
    "scene file missing": (no_change, SIMULATE, r"scene.toml: file not found"),
    "scene without objects": (scene('name = "x"\n'), SIMULATE, r"scene.toml: top level: missing field 'objects'"),
    "scene object without material": (scene(SPHERE.replace('material = "paint"\n', "")), SIMULATE,
                                      r"scene.toml: \[\[objects\]\] #1: missing field 'material'"),
    "scene unknown shape": (scene(SPHERE.replace('"sphere"', '"sphre"')), SIMULATE,
                            r"scene.toml: \[\[objects\]\] #1 \('ball'\): shape must be one of \[.*\], got 'sphre'"),
    "scene misspelt shape parameter": (scene(SPHERE.replace("radius_m", "radus_m")), SIMULATE,
                                       r"scene.toml: \[\[objects\]\] #1 \('ball'\): .*radus_m"),
    "scene negative radius": (scene(SPHERE.replace("0.1", "-0.1")), SIMULATE,
                              r"scene.toml: \[\[objects\]\] #1 \('ball'\): .*radius"),
    "scene undefined material": (scene(SPHERE.replace('material = "paint"', 'material = "gold"')), SIMULATE,
                                 r"scene.toml: \[\[objects\]\] #1 \('ball'\): material 'gold' is not defined; "
                                 r"defined: \['paint'\]"),
    "scene misspelt rig field": (scene(SPHERE + "[rig]\ndistanc_m = 1.0\n"), SIMULATE,
                                 r"scene.toml: \[rig\]: unknown field 'distanc_m' \(did you mean 'distance_m'\?\)"),
    "scene bad bit depth": (scene(SPHERE + "[sensor]\nbit_depth = 7\n"), SIMULATE,
                            r"scene.toml: \[sensor\]: sensor bit_depth must be 8, 12 or 16, got 7"),
    "scene unknown material kind": (scene(SPHERE.replace('"matte"', '"shiny"')), SIMULATE,
                                    r"scene.toml: \[materials.paint\]: material 'paint': kind must be one of "
                                    r"\('matte', 'dark', 'metal'\), got 'shiny'"),
    "scene mesh file missing": (scene(SPHERE.replace('shape = "sphere"\nradius_m = 0.1', 'shape = "mesh"\nfile = "m.stl"')),
                                SIMULATE, r"m.stl: mesh file not found"),
    "simulate unknown mode": (no_change, ["simulate", "{s}/out", "--mode", "blob"],
                              r"--mode must be 'spot' or 'stripe', got 'blob'"),
    "simulate unknown target": (no_change, ["simulate", "{s}/out", "--target", "hexagon"],
                                r"target kind must be one of \['charuco', 'chessboard', 'cube'\], got 'hexagon'"),
    "simulate into a file": (no_change, ["simulate", "{s}/rig.toml", "--frames", "1"],
                             r"rig.toml: output session folder is an existing file"),
    "design without an object": (no_change, ["design", "--out", "{s}/design"],
                                 r"give exactly one of --mesh FILE or --scene NAME"),
    "design mesh missing": (no_change, ["design", "--out", "{s}/design", "--mesh", "{s}/nope.stl"],
                            r"nope.stl: not a readable mesh"),
    "design mesh of unknown type": (no_change, ["design", "--out", "{s}/design", "--mesh", "{s}/rig.toml"],
                                    r"rig.toml: not a readable mesh: file_type 'toml' not supported"),
    "design spec misspelt table": (write_text("spec.toml", "[camra]\n"), DESIGN,
                                   r"spec.toml: top level: unknown field 'camra' \(did you mean 'camera'\?\)"),
    "design spec negative width": (write_text("spec.toml", "[camera]\nwidth_px = -5\n"), DESIGN,
                                   r"spec.toml: \[camera\] width_px must be a positive integer, got -5"),
    "design spec NaN target": (write_text("spec.toml", "[target]\nsigma_m = nan\n"), DESIGN,
                               r"spec.toml: \[target\] sigma_m must be a positive number, got nan"),
    "design spec unknown mounting": (write_text("spec.toml", "[mounting]\nshape = 'cube'\n"), DESIGN,
                                     r'spec.toml: \[mounting\] shape must be "cylinder" or "sphere", got \'cube\''),
    "design spec missing candidate rig": (write_text("spec.toml", "[mounting]\nrig = 'nope.toml'\n"), DESIGN,
                                          r"nope.toml: file not found"),
    "design too few cameras": (no_change, ["design", "--out", "{s}/design", "--scene", "sphere", "--cameras", "1"],
                               r"cameras must be an integer >= 2 \(target min_views\), got 1"),
    "scan without a rig": (no_change, ["scan", "{s}/sc"],
                           r"give exactly one rig: --sim SCENE, --replay FOLDER or --camera NAME=SOURCE \(got none\)"),
    "scan with two rigs": (no_change, ["scan", "{s}/sc", "--sim", "sphere", "--replay", "{s}"],
                           r"give exactly one rig: .* \(got \['--sim', '--replay'\]\)"),
    "scan bad ROI": (no_change, ["scan", "{s}/sc", "--sim", "sphere", "--roi-mm", "1,2,3"],
                     r"--roi-mm must be 6 comma-separated numbers, got '1,2,3'"),
    "scan bad camera source": (no_change, ["scan", "{s}/sc", "--camera", "cam0"],
                               r"--camera must be NAME=SOURCE \(device index, URL or video file\), got 'cam0'"),
    "scan real rig without head": (no_change, ["scan", "{s}/sc", "--camera", "cam0=0"],
                                   r"a real rig needs --gcode PORT, --head-mm X,Y,Z and --roi-mm besides --camera"),
    "scan resume without manifest": (no_change, ["scan", "{s}/sc", "--sim", "sphere", "--resume"],
                                     r"sc/scan/manifest.jsonl: no scan manifest to resume"),
    "scan resume of a malformed manifest": (malformed_manifest, ["scan", "{s}/sc", "--sim", "sphere", "--resume"],
                                            r"sc/scan/manifest.jsonl: record 1: malformed record \(KeyError: 'cameras'\)"),
    "scan into an image session": (no_change, ["scan", "{s}", "--sim", "sphere"],
                                   r"scan already holds camera folders but no manifest; use a new session folder"),
    "scan replay of a missing folder": (no_change, ["scan", "{s}/sc", "--replay", "{s}/nope", "--roi-mm", "0,0,0,1,1,1"],
                                        r"nope: session folder not found"),
    "scan replay without plan or ROI": (no_change, ["scan", "{s}/sc", "--replay", "{s}"],
                                        r"--roi-mm is needed to replay .*: it holds no scan manifest with a plan"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_simulate_design_scan_bad_input(good_session, capsys, case):
    setup, argv, message = CASES[case]
    setup(good_session)
    capsys.readouterr()
    argv = [a.format(s=good_session) for a in argv]
    assert_fails_cleanly(argv, message, good_session, capsys)


#: Out-of-range options are refused by typer itself: exit 2, the option named, no traceback.
USAGE = {
    "reconstruct --gate 2": (["reconstruct", "{s}", "--gate", "2"], r"--gate"),
    "reconstruct --sigma-floor-px -1": (["reconstruct", "{s}", "--sigma-floor-px", "-1"], r"--sigma-floor-px"),
    "evaluate --outlier-mm -1": (["evaluate", "{s}/points.ply", "--outlier-mm", "-1"], r"--outlier-mm"),
    "simulate --cameras 9": (["simulate", "{s}/out", "--cameras", "9"], r"--cameras"),
    "detect --workers abc": (["detect", "{s}", "--workers", "abc"], r"--workers"),
    "unknown verb": (["detekt", "{s}"], r"detekt"),
}


@pytest.mark.parametrize("case", list(USAGE))
def test_usage_errors(good_session, capsys, case):
    from scanrig.cli.main import main

    argv, option = USAGE[case]
    before = snapshot(good_session)
    capsys.readouterr()
    assert main([a.format(s=good_session) for a in argv]) == 2
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err + captured.out
    assert re.search(option, captured.err)
    assert snapshot(good_session) == before

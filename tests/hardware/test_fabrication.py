"""``tumblebot build``: the fabrication package, read back with parsers of its own.

The DXF files are read with a minimal group-code reader written here from the DXF
reference (not ezdxf, which wrote them), the SVG files with ElementTree, the glTF with
trimesh; the parts list is compared with ``tumblebot power --json``.
"""

from __future__ import annotations

import csv
import json
import re
import xml.etree.ElementTree as ET
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from tests.helpers import tb, tb_ok
from tumblebot.sim.hardware.layout import MARKERS
from tumblebot.sim.hardware.package import bom
from tumblebot.sim.world.catalogue import CatalogueError, catalogue, default_servo, servo
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import DEFAULT_MASS_MODEL
from tumblebot.sim.world.power import power_breakdown

DESIGNS = {
    "xi3": (0.292, 0.129, 0.098, 0.136),
    "smallest": (0.189, 0.102, 0.084, 0.066),
    "largest": (0.300, 0.250, 0.200, 0.250),
}




def read_dxf(path: Path) -> list[dict[str, Any]]:
    """ENTITIES of a DXF file as dicts: type, layer, and the group codes a laser cutter uses
    (10/20 points, 40 radius, 70 flags)."""
    lines = path.read_text().splitlines()
    pairs = [(int(lines[i].strip()), lines[i + 1].strip()) for i in range(0, len(lines) - 1, 2)]
    entities: list[dict[str, Any]] = []
    in_entities = False
    current: dict[str, Any] | None = None
    for i, (code, value) in enumerate(pairs):
        if code == 2 and i > 0 and pairs[i - 1] == (0, "SECTION"):
            in_entities = value == "ENTITIES"
            continue
        if not in_entities:
            continue
        if code == 0:
            current = {"type": value, "xs": [], "ys": []}
            entities.append(current)
        elif current is not None:
            if code == 8:
                current["layer"] = value
            elif code == 10:
                current["xs"].append(float(value))
            elif code == 20:
                current["ys"].append(float(value))
            elif code == 40:
                current["r"] = float(value)
            elif code == 70:
                current["flags"] = int(value)
    return [e for e in entities if e["type"] not in ("ENDSEC", "EOF")]


@pytest.fixture(scope="module", params=list(DESIGNS))
def package(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[Design, Path]:
    design = DESIGNS[request.param]
    out = tmp_path_factory.mktemp(request.param) / "pkg"
    run = tb_ok("build", "--design", ",".join(map(str, design)), "-o", str(out))
    assert "wrote the fabrication package" in run.stdout
    return Design(*design), out


@pytest.mark.slow
def test_that_the_package_has_every_file_and_its_bom_total_is_the_power_models_mass(package: tuple[Design, Path]
                                                                                      ) -> None:
    w, out = package
    record = json.loads((out / "package.json").read_text())
    for name in record["files"]:
        assert (out / name).stat().st_size > 0, name
    pictures = re.findall(r"!\[[^]]*\]\(([^)]+)\)", (out / "assembly.md").read_text())
    assert {"robot.png", "wiring.png", "assembly-1.png", "assembly-4.png"} <= set(pictures)
    assert all(name in record["files"] for name in pictures)  # every picture the guide shows is written
    with (out / "bom.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    assert {"part", "quantity", "material", "size_mm", "mass_kg"} <= set(rows[0])
    parts = [r for r in rows if r["part"] != "total"]
    total = sum(float(r["mass_kg"]) for r in parts)
    power = json.loads(tb("power", *map(str, w.as_tuple()), "--json").stdout)
    assert total == pytest.approx(power["mass"], rel=1e-3)
    assert float(next(r for r in rows if r["part"] == "total")["mass_kg"]) == pytest.approx(total, abs=1e-5)
    assert "| **total** |" in (out / "bom.md").read_text()


@pytest.mark.slow
def test_that_the_side_plate_dxf_reads_back_to_the_designs_numbers(package: tuple[Design, Path]) -> None:
    w, out = package
    for side in ("right", "left"):
        entities = read_dxf(out / "cut" / f"side_plate_{side}.dxf")
        cut = [e for e in entities if e.get("layer") == "CUT"]
        outlines = [e for e in cut if e["type"] == "LWPOLYLINE"]
        plate = max(outlines, key=lambda e: max(e["xs"]) - min(e["xs"]))
        xs, ys = plate["xs"], plate["ys"]
        assert isinstance(xs, list) and isinstance(ys, list)
        assert plate.get("flags", 0) & 1  # closed
        assert max(xs) - min(xs) == pytest.approx(w.y * 1e3, abs=0.01)
        assert max(ys) - min(ys) == pytest.approx(w.z * 1e3, abs=0.01)
        holes = sorted((e["xs"][0], e["ys"][0], e["r"]) for e in cut if e["type"] == "CIRCLE"
                       and abs(e["r"] - 4.25) < 1e-6)
        hu, hv = (w.y / 2 - DEFAULT_MASS_MODEL.rod_inset) * 1e3, (w.z / 2 - DEFAULT_MASS_MODEL.rod_inset) * 1e3
        expect = sorted((su * hu, sv * hv, 4.25) for su in (-1, 1) for sv in (-1, 1))
        assert [v for h in holes for v in h] == pytest.approx([v for h in expect for v in h], abs=0.01)
        marks = [e for e in entities if e.get("layer") == "ENGRAVE" and e["type"] == "CIRCLE"]
        assert len(marks) == len(MARKERS[side])
        # the servo's shaft is on the plate's centre: the case cut-out spans it
        cutouts = [e for e in outlines if e is not plate]
        assert any(min(e["xs"]) < 0 < max(e["xs"]) and min(e["ys"]) < 0 < max(e["ys"])
                   for e in cutouts)


@pytest.mark.slow
def test_that_the_svg_cut_files_are_in_millimetres_and_match_the_dxf(package: tuple[Design, Path]) -> None:
    w, out = package
    ns = {"s": "http://www.w3.org/2000/svg"}
    root = ET.parse(out / "cut" / "side_plate_right.svg").getroot()
    assert root.get("width", "").endswith("mm")
    cut = root.find("s:g[@id='CUT']", ns)
    assert cut is not None
    rects = cut.findall("s:rect", ns)
    plate = max(rects, key=lambda r: float(r.get("width", 0)))
    assert float(plate.get("width", 0)) == pytest.approx(w.y * 1e3, abs=0.01)
    assert float(plate.get("height", 0)) == pytest.approx(w.z * 1e3, abs=0.01)
    assert len([c for c in cut.findall("s:circle", ns) if abs(float(c.get("r", 0)) - 4.25) < 1e-6]) == 4
    leg = ET.parse(out / "cut" / "leg.svg").getroot().find("s:g[@id='CUT']/s:rect", ns)
    assert leg is not None and float(leg.get("height", 0)) == pytest.approx(w.l * 1e3 + 7.5, abs=0.01)


@pytest.mark.slow
def test_that_the_3d_assembly_loads_with_the_bodys_size_and_the_mass_models_mass(package: tuple[Design, Path]
                                                                                   ) -> None:
    import trimesh

    w, out = package
    scene = trimesh.load(str(out / "robot.glb"), force="scene")
    (x0, y0, z0), (x1, y1, z1) = scene.bounds  # glTF: metres, y up (the body's z), z the body's -y
    m = DEFAULT_MASS_MODEL
    leg_outer = w.x / 2 - m.rod_overhang + m.servo.flange_to_horn_mm / 1e3 - m.plate_thickness - m.mount_thickness
    assert x1 - x0 == pytest.approx(2 * (leg_outer + m.leg_thickness), abs=2e-4)
    assert z1 - z0 == pytest.approx(w.y, abs=2e-4)
    assert (y0, y1) == pytest.approx((-w.z / 2, w.l), abs=2e-4)  # the body's bottom, the legs' feet (pointing up)
    record = json.loads((out / "package.json").read_text())
    assert abs(record["cad"]["mass"] / m.total_mass(w) - 1) < 0.02
    cad, urdf = record["cad"], record["urdf"]
    for axis in range(3):
        assert cad["inertia"][axis][axis] == pytest.approx(urdf["inertia"][axis][axis], rel=0.05)
    assert cad["com"] == pytest.approx(urdf["com"], abs=0.05 * w.pivot_radius)
    step = (out / "robot.step").read_text(errors="replace")
    assert step.startswith("ISO-10303-21") and "MANIFOLD_SOLID_BREP" in step


def test_that_the_catalogues_default_servo_is_the_simulators() -> None:
    from tumblebot.sim.world import constants as C

    spec = default_servo()
    assert spec.name == "thesis" and DEFAULT_MASS_MODEL.servo == spec
    assert spec.free_speed == pytest.approx(C.LEG_SPEED)
    assert spec.stall_torque == pytest.approx(C.STALL_TORQUE, rel=1e-3)
    assert len(catalogue()) >= 3 and all(s.datasheet for s in catalogue().values())
    with pytest.raises(CatalogueError, match="unknown servo 'nope'"):
        servo("nope")


def test_that_one_constant_moves_the_parts_list_the_mass_and_the_energy_together() -> None:
    w = Design(0.292, 0.129, 0.098, 0.136)
    heavier = replace(DEFAULT_MASS_MODEL, plate_density=900.0)
    for model in (DEFAULT_MASS_MODEL, heavier, replace(DEFAULT_MASS_MODEL, servo=servo("parallax-feedback-360"))):
        assert sum(r.mass for r in bom(w, model)) == pytest.approx(model.total_mass(w), rel=1e-9)
        assert power_breakdown(w, model).mass == pytest.approx(model.total_mass(w))
    assert power_breakdown(w, heavier).e > power_breakdown(w, DEFAULT_MASS_MODEL).e


@pytest.mark.slow
def test_that_build_with_another_servo_draws_its_mount_and_weighs_its_mass(tmp_path: Path) -> None:
    out = tmp_path / "fs90r"
    tb_ok("build", "--design", "0.292,0.129,0.098,0.136", "--servo", "feetech-fs90r", "-o", str(out))
    mount = read_dxf(out / "cut" / "motor_mount.dxf")
    outline = max((e for e in mount if e["type"] == "LWPOLYLINE"), key=lambda e: max(e["xs"]) - min(e["xs"]))
    width = max(outline["xs"]) - min(outline["xs"])
    assert width == pytest.approx(servo("feetech-fs90r").flange_length_mm + 12.0, abs=0.01)
    model = replace(DEFAULT_MASS_MODEL, servo=servo("feetech-fs90r"))
    assert json.loads((out / "package.json").read_text())["bom_kg"] == pytest.approx(
        model.total_mass(Design(0.292, 0.129, 0.098, 0.136)))


def test_that_bad_build_input_gets_one_clear_error_and_writes_nothing(tmp_path: Path) -> None:
    out = tmp_path / "pkg"
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("mine")
    cases = [
        (("build", "-o", str(out)), "give --design"),
        (("build", "--design", "0.1,0.1,0.1,0.1", "-o", str(out)), "outside its bound"),
        (("build", "--design", "0.2,0.2,nan,0.2", "-o", str(out)), "not finite"),
        (("build", "--design", "0.292,0.129,0.098,0.136", "--servo", "nope", "-o", str(out)), "unknown servo"),
        (("build", "--design", "0.292,0.129,0.098,0.136", "--study", "s", "-o", str(out)), "go with --storage"),
        (("build", "--storage", f"sqlite:///{tmp_path / 'none.db'}", "--study", "s", "-o", str(out)), ""),
        (("build", "--design", "0.292,0.129,0.098,0.136", "-o", str(busy)), "not an empty folder"),
    ]
    for args, message in cases:
        run = tb(*args)
        assert run.returncode == 2, (args, run.stderr)
        lines = run.stderr.strip().splitlines()
        assert len(lines) == 1 and message in lines[0] and "Traceback" not in run.stderr, (args, run.stderr)
    assert not out.exists() and (busy / "keep.txt").read_text() == "mine" and len(list(busy.iterdir())) == 1

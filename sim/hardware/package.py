"""``tumblebot build``: the fabrication package of one design.

:func:`build_package` writes, into one folder: the parts list (``bom.csv``, ``bom.md``),
the laser-cutter files (``cut/*.dxf``, ``cut/*.svg``), the 3D assembly (``robot.step``,
``robot.glb``, ``robot.png``), the wiring diagram (``wiring.svg``, ``wiring.png``), the
mocap marker positions (``markers.csv``), the assembly guide (``assembly.md``) and a
``package.json`` that records the design, the servo and the checks of the assembly's mass,
centre of mass and inertia against the mass model and the URDF.
"""

from __future__ import annotations

import csv
import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from tumblebot.sim.hardware import cad
from tumblebot.sim.hardware.cutfiles import write_dxf, write_svg
from tumblebot.sim.hardware.guide import write_guide, write_wiring
from tumblebot.sim.hardware.layout import LEG_TAIL, flat_parts, leg_plane_offset, marker_table
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import MassModel
from tumblebot.sim.world.power import power_breakdown

BOM_COLUMNS = ("part", "quantity", "material", "size_mm", "unit_mass_kg", "mass_kg", "note")


@dataclass(frozen=True)
class BomRow:
    part: str
    quantity: int
    material: str
    size_mm: str
    unit_mass: float
    note: str = ""

    @property
    def mass(self) -> float:
        return self.quantity * self.unit_mass


def bom(w: Design, mass: MassModel) -> list[BomRow]:
    """The parts list; its masses are the mass model's, so its total is ``m(w)``."""
    s = mass.servo
    y, z, x, l = (round(v * 1e3, 1) for v in (w.y, w.z, w.x, w.l))  # noqa: E741
    nuts = mass.rod_count * 4
    mu, mv = (round(v * 1e3, 1) for v in mass.mount_outline())
    return [
        BomRow("side plate", 2, "MDF 4 mm", f"{y:g} x {z:g} x {mass.plate_thickness * 1e3:g}", mass.plate_mass(w),
               "cut/side_plate_right.*, cut/side_plate_left.* (cut-outs taken off the mass)"),
        BomRow("threaded rod M8", mass.rod_count, "zinc-plated steel", f"M8 x {x:g}", mass.rod_mass(w),
               f"cut to {x:g} mm, ends deburred"),
        BomRow("M8 nut with washer", nuts, "steel", "M8", mass.hardware_mass / nuts,
               f"{nuts // 2} full nuts (inside the plates), {nuts // 2} jam nuts (outside), {nuts} washers"),
        BomRow("leg", 2, "Delrin (POM) 3 mm", f"{mass.leg_width * 1e3:g} x {l + LEG_TAIL:g} x "
               f"{mass.leg_thickness * 1e3:g}", mass.leg_mass(w),
               f"cut/leg.*: {l:g} mm from the axis hole to the foot"),
        BomRow("motor mount", 2, "Delrin (POM) 3 mm", f"{mu:g} x {mv:g} x {mass.mount_thickness * 1e3:g}",
               mass.mount_mass(), "cut/motor_mount.*"),
        BomRow("servo", 2, s.part, " x ".join(f"{v:g}" for v in s.body_mm), s.mass,
               f"catalogue entry '{s.name}', with its horn and screws"),
        BomRow("electronics board", 1, "Raspberry Pi 3B+, Arduino Uno, wiring",
               " x ".join(f"{v * 1e3:g}" for v in mass.electronics_size), mass.electronics_mass,
               "centred between the plates"),
    ]


def write_bom(rows: list[BomRow], folder: Path) -> float:
    """``bom.csv`` and ``bom.md``; returns the total mass, kg."""
    total = sum(r.mass for r in rows)
    with (folder / "bom.csv").open("w", newline="") as fh:
        out = csv.writer(fh)
        out.writerow(BOM_COLUMNS)
        for r in rows:
            out.writerow([r.part, r.quantity, r.material, r.size_mm, f"{r.unit_mass:.6f}", f"{r.mass:.6f}", r.note])
        out.writerow(["total", sum(r.quantity for r in rows), "", "", "", f"{total:.6f}", "m(w) of the mass model"])
    lines = ["| part | qty | material | size (mm) | unit mass (g) | mass (g) | note |",
             "|---|---:|---|---|---:|---:|---|"]
    lines += [f"| {r.part} | {r.quantity} | {r.material} | {r.size_mm} | {r.unit_mass * 1e3:.1f} | "
              f"{r.mass * 1e3:.1f} | {r.note} |" for r in rows]
    lines.append(f"| **total** | | | | | **{total * 1e3:.1f}** | the mass model's m(w) |")
    (folder / "bom.md").write_text("# Parts list\n\n" + "\n".join(lines) + "\n")
    return total


def battery_allowance(w: Design, mass: MassModel, tolerance: float = 0.02) -> float:
    """The largest mass (kg) a battery could add before ``e(w)`` rises by ``tolerance``."""
    base = power_breakdown(w, mass).e
    if not np.isfinite(base):
        return float("nan")
    lo, hi = 0.0, 0.5
    for _ in range(40):
        mid = (lo + hi) / 2
        e = power_breakdown(w, replace(mass, electronics_mass=mass.electronics_mass + mid)).e
        lo, hi = (mid, hi) if e <= base * (1 + tolerance) else (lo, mid)
    return lo


def build_package(w: Design, mass: MassModel, out: Path, progress: Callable[[str], None] = lambda _: None
                  ) -> dict[str, Any]:
    """Write the package for design ``w`` (the mass model carries the servo) into ``out``;
    returns what ``package.json`` records."""
    from tumblebot.sim.world.robot import RobotModel, urdf_mass_properties

    out.mkdir(parents=True, exist_ok=True)
    (out / "cut").mkdir(exist_ok=True)
    progress("parts list")
    rows = bom(w, mass)
    total = write_bom(rows, out)
    progress("laser-cutter files")
    parts = [part for part, _ in flat_parts(w, mass)]
    for part in parts:
        write_dxf(part, out / "cut" / f"{part.name}.dxf")
        write_svg(part, out / "cut" / f"{part.name}.svg")
    with (out / "markers.csv").open("w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(("marker", "x_mm", "y_mm", "z_mm"))
        writer.writerows(marker_table(w, mass))
    progress("3D assembly (build123d)")
    solids = cad.assembly(w, mass)
    props = cad.mass_properties(solids)
    cad.write_assembly(solids, out / "robot.step", out / "robot.glb")
    cad.render_png(out / "robot.glb", out / "robot.png", f"tumblebot {w}")
    steps = cad.render_steps(out / "robot.glb", out)
    progress("wiring diagram and assembly guide")
    write_wiring(out, mass.servo)
    urdf = urdf_mass_properties(RobotModel.from_design(w, mass))
    power = power_breakdown(w, mass)
    record: dict[str, Any] = {
        "design": w.as_dict(), "servo": mass.servo.as_dict(), "mass_model_kg": mass.total_mass(w), "bom_kg": total,
        "e": power.e if power.can_tumble else None,
        "cad": props, "urdf": urdf,
        "cad_mass_error": props["mass"] / mass.total_mass(w) - 1,
        "leg_plane_mm": dict(zip(("built", "simulated"), leg_plane_offset(mass), strict=True)),
        "battery_allowance_kg": battery_allowance(w, mass),
        "files": ["bom.csv", "bom.md", "assembly.md", "markers.csv", "robot.step", "robot.glb", "robot.png", *steps,
                  "wiring.svg", "wiring.png",
                  *sorted(f"cut/{p.name}.{ext}" for p in parts for ext in ("dxf", "svg"))],
    }
    write_guide(out, w, mass, rows, record)
    (out / "package.json").write_text(json.dumps(record, indent=2) + "\n")
    return record

"""``assembly.md`` and the wiring diagram: how to cut, assemble, wire, flash and track the
robot of one design."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from tumblebot.sim.hardware.layout import HORN_ARM_HOLE, HORN_SCREW_HOLE, LEG_TAIL, MARKER_DIAMETER, marker_table
from tumblebot.sim.world.catalogue import ServoSpec
from tumblebot.sim.world.design import Design
from tumblebot.sim.world.mass import MassModel

SERVO_SUPPLY_A = 3.0  #: A, a bench supply for two stalled standard servos with margin


def write_wiring(folder: Path, servo: ServoSpec) -> None:
    """The wiring and power diagram, as SVG and PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyBboxPatch

    fig, ax = plt.subplots(figsize=(9, 5.2), dpi=110)
    ax.set_xlim(0, 100)
    ax.set_ylim(0, 60)
    ax.axis("off")
    boxes = {
        "bench": (2, 42, 24, 14, f"bench supply\n{servo.voltage:g} V, ≥ {SERVO_SUPPLY_A:g} A\n(servos)"),
        "usb": (2, 4, 24, 12, "USB supply\n5.1 V, 2.5 A\n(Raspberry Pi)"),
        "pi": (38, 4, 22, 14, "Raspberry Pi 3B+\n(agent, Wi-Fi to host)"),
        "uno": (38, 28, 22, 14, "Arduino Uno\n(firmware)"),
        "right": (74, 42, 24, 12, "right servo (+x)\nsignal ← D9"),
        "left": (74, 22, 24, 12, "left servo (−x)\nsignal ← D10"),
    }
    for x, y, wd, ht, text in boxes.values():
        ax.add_patch(FancyBboxPatch((x, y), wd, ht, boxstyle="round,pad=0.6", fc="#f4f4f4", ec="#333333"))
        ax.text(x + wd / 2, y + ht / 2, text, ha="center", va="center", fontsize=8.5)

    def wire(points: list[tuple[float, float]], colour: str, label: str = "") -> None:
        xs, ys = zip(*points, strict=True)
        ax.plot(xs, ys, color=colour, lw=2)
        if label:
            ax.text(xs[len(xs) // 2] + 0.5, ys[len(ys) // 2] + 0.8, label, color=colour, fontsize=7.5)

    wire([(26, 53), (70, 53), (74, 50)], "#c00000", f"V+ {servo.voltage:g} V")
    wire([(70, 53), (70, 30), (74, 30)], "#c00000")
    wire([(26, 45), (66, 45), (74, 44)], "#000000", "GND (common)")
    wire([(66, 45), (66, 24), (74, 24)], "#000000")
    wire([(66, 35), (60.6, 35)], "#000000", "")
    wire([(60.6, 38), (72, 38), (74, 52)], "#e0a000", "D9")
    wire([(60.6, 31), (68, 31), (74, 28)], "#e0a000", "D10")
    wire([(26, 10), (37.4, 10)], "#c00000", "micro-USB 5 V")
    wire([(49, 18.6), (49, 27.4)], "#1f4fbf", "USB A–B (serial + Uno power)")
    ax.text(50, 1, "One tether from the bench carries both supplies; the Uno's GND joins the servo supply's GND "
            "(never power servos from the Uno's 5 V pin).", ha="center", fontsize=7.5)
    fig.tight_layout()
    fig.savefig(folder / "wiring.svg")
    fig.savefig(folder / "wiring.png")
    plt.close(fig)


def write_guide(out: Path, w: Design, mass: MassModel, rows: list[Any], record: dict[str, Any]) -> None:
    s = mass.servo
    x, y, z, l = (v * 1e3 for v in (w.x, w.y, w.z, w.l))  # noqa: E741
    built, simulated = record["leg_plane_mm"]["built"], record["leg_plane_mm"]["simulated"]
    spacer = simulated - built
    leg_note = (f"a {spacer:.1f} mm spacer (washers) between the horn and the leg puts it where the simulator has it"
                if spacer > 0.5 else
                f"the leg sits {-spacer:.1f} mm further out than the simulator has it (no effect on the motion that "
                "matters: the legs turn in planes parallel to the plates)" if spacer < -0.5 else
                "the leg sits where the simulator has it")
    battery = record["battery_allowance_kg"]
    markers = "\n".join(f"| {name} | {mx:+.1f} | {my:+.1f} | {mz:+.1f} |" for name, mx, my, mz in marker_table(w, mass))
    cad_err = 100 * record["cad_mass_error"]
    e_text = f"{record['e']:.3f} W/m" if record["e"] is not None else "cannot tumble (e = inf)"
    text = f"""# Building the robot x = {x:.1f} mm, y = {y:.1f} mm, z = {z:.1f} mm, l = {l:.1f} mm

Everything here comes from the same component model as the simulator's mass and the power
model: mass {record['mass_model_kg'] * 1e3:.1f} g, e(w) = {e_text}. The 3D assembly
(`robot.step`, `robot.glb`) weighs {record['cad']['mass'] * 1e3:.1f} g ({cad_err:+.2f} % against the model).

![the assembly](robot.png)

## 1. Parts

See [bom.md](bom.md) (also `bom.csv`). Servo: **{s.part}** (catalogue entry `{s.name}`):
free speed {s.free_speed:g} rad/s and stall torque {s.stall_torque:g} N·m at {s.voltage:g} V,
{s.mass * 1e3:g} g, case {' x '.join(f'{v:g}' for v in s.body_mm)} mm. Source: {s.datasheet}.
{s.notes}

## 2. Cutting

Cut the files in `cut/` (DXF or SVG, millimetres; layer `CUT` red, layer `ENGRAVE` blue):
`side_plate_right` and `side_plate_left` once each from 4 mm MDF, **engraved face up** (the
engraved face is the outside), `motor_mount` twice and `leg` twice from 3 mm Delrin.

- Side plate: {y:.1f} x {z:.1f} mm; four {mass.rod_hole_diameter * 1e3:g} mm rod holes at
  {mass.rod_inset * 1e3:g} mm from the edges; the servo's case cut-out with its
  {s.mount_hole_diameter_mm:g} mm screw holes, placed so that the output shaft is on the
  plate's centre (the leg axis); the mocap marker spots engraved.
- Leg: {mass.leg_width * 1e3:g} mm wide, {l:.1f} mm from the centre of its {HORN_SCREW_HOLE:g} mm
  axis hole to the foot, plus {LEG_TAIL:g} mm behind the axis; a {HORN_ARM_HOLE:g} mm hole
  {s.horn_hole_radius_mm:g} mm along it for a horn screw.

## 3. Assembly

1. Cut the four M8 rods to **{x:.1f} mm** (this length is the body width x).
2. On each rod, thread a washer and a full nut to **{mass.rod_overhang * 1e3 + mass.plate_thickness * 1e3:.1f} mm**
   from each end (the nut's outer face at that distance), so that the plates sit
   {mass.rod_overhang * 1e3:g} mm in from the rod ends; the inner faces of the two plates are then
   {x - 2 * (mass.rod_overhang + mass.plate_thickness) * 1e3:.1f} mm apart.

   ![steps 1-2](assembly-1.png)
3. Put a motor mount on the inner face of each plate over the cut-out, push a servo in from the
   inside (its flange on the mount, the output shaft through the plate's centre) and fix it with
   its screws through the flange, the mount and the plate.

   ![step 3](assembly-2.png)
4. Slide the plates onto the rods (engraved faces out), then a washer and a jam nut on each rod
   end outside: the rod end is flush with the jam nut, {mass.rod_overhang * 1e3:g} mm outside the
   plate. Square the frame, tighten the nuts against the plates.

   ![step 4](assembly-3.png)
5. Strap the electronics board between the rods at the body's centre with cable ties, the Uno's
   USB socket reachable.

   ![step 5](assembly-4.png)
6. Legs: set each servo to neutral (below), put the horn on the spline, then fix the leg to the
   horn with the horn's centre screw through the leg's axis hole and one small self-tapping screw
   through the leg's second hole into the horn's arm. Both legs point the same way. As built, the
   leg's inner face is {built:.1f} mm outside the plate; the simulator has it {simulated:.1f} mm
   out: {leg_note}.

## 4. Wiring and power

![wiring](wiring.png)

The servos run from a **{s.voltage:g} V bench supply (at least {SERVO_SUPPLY_A:g} A)**, the Pi from a
5.1 V 2.5 A USB supply, both through one light tether from above the test area; the Uno is
powered and talked to over its USB cable from the Pi. Join the Uno's GND to the servo supply's
GND. Right servo (+x side) signal on **D9**, left (−x) on **D10**. There is no battery in the
mass model: a battery would be extra mass the optimiser did not see. The design assumes the
tether; a battery of up to {battery * 1e3:.0f} g keeps e(w) within 2 % of this package's value,
so a small pack (with a 6 V regulator for the servos) is possible, but then re-run the
optimiser with its mass in the model.

## 5. Firmware

Build and flash the Uno from this repository: `make -C firmware/arduino flash PORT=/dev/ttyACM0`
(needs Debian's `avrdude`, which `./dev.sh` installs), or `pio run -e uno -t upload`.

## 6. Servo neutral and direction

A continuous-rotation servo creeps when its neutral pulse is off. With the agent running and the
robot stopped, show the trims the Uno holds, `tumblebot trim --agent PI:47800 --key KEY`, and, for a
servo whose leg creeps, move its neutral in 5 µs steps until the leg stays still for 10 s
(`tumblebot trim ... --servo right --nudge -5`: lower the neutral when the right leg creeps forward,
raise it when it creeps backward; the left servo is mirrored, so the other way round). A servo with
a neutral trimmer (a small potentiometer in its case) can be set with it instead, at 1500 µs. If a
leg turns backward when told forward, flip that servo's direction (`--direction`). The Uno keeps
the trims in EEPROM.

## 7. Check before trials

`tumblebot bench check --agent PI:47800 --key KEY --mocap URL` checks the agent, the Uno, the trims,
the motion capture frame, that the robot keeps still when stopped, that each servo turns both ways
and that the legs stop when the host falls silent, one line each. The robot moves: give it 0.5 m of
clear floor.

## 8. Motion capture

Stick {MARKER_DIAMETER:g} mm flat-based hemispherical markers on the engraved spots (three on the right
plate, two on the left: the set is asymmetric, so the pose is unique). Their base centres in the
simulator's body frame (x along the leg axis toward the right plate, z up when the robot lies flat;
millimetres) are in `markers.csv`:

| marker | x | y | z |
|---|---:|---:|---:|
{markers}

Define the rigid body with the robot lying flat on the floor, legs up, right plate toward the
lab's +x: set the rigid body's origin to the body centre (the mean of the plates' centres: the
table's origin) and its axes to the lab's, so that its frame is the simulator's (z up).
"""
    (out / "assembly.md").write_text(text)

"""Laser-cutter files: DXF (with ezdxf) and SVG, in millimetres.

Cut paths are on layer ``CUT`` (red in the SVG), marks on layer ``ENGRAVE`` (blue): the
mocap marker positions and each part's label. A part's outline is a closed polyline, its
round holes are circles and its rectangular holes closed polylines.
"""

from __future__ import annotations

from pathlib import Path
from xml.sax.saxutils import escape

from tumblebot.sim.hardware.layout import Circle, FlatPart, Rect

CUT, ENGRAVE = "CUT", "ENGRAVE"
SVG_COLOURS = {CUT: "#ff0000", ENGRAVE: "#0000ff"}
MARGIN = 5.0  #: mm around a part in the SVG


def _corners(r: Rect) -> list[tuple[float, float]]:
    hu, hv = r.width / 2, r.height / 2
    return [(r.u - hu, r.v - hv), (r.u + hu, r.v - hv), (r.u + hu, r.v + hv), (r.u - hu, r.v + hv)]


def write_dxf(part: FlatPart, path: Path) -> None:
    from ezdxf import filemanagement, units
    from ezdxf.enums import TextEntityAlignment

    doc = filemanagement.new("R2010", setup=True)
    doc.units = units.MM
    doc.header["$MEASUREMENT"] = 1  # metric
    doc.layers.add(CUT, color=1)  # red
    doc.layers.add(ENGRAVE, color=5)  # blue
    msp = doc.modelspace()
    msp.add_lwpolyline(_corners(part.outline), close=True, dxfattribs={"layer": CUT})
    for hole in part.holes:
        if isinstance(hole, Circle):
            msp.add_circle((hole.u, hole.v), hole.diameter / 2, dxfattribs={"layer": CUT})
        else:
            msp.add_lwpolyline(_corners(hole), close=True, dxfattribs={"layer": CUT})
    for mark in part.marks:
        msp.add_circle((mark.u, mark.v), mark.diameter / 2, dxfattribs={"layer": ENGRAVE})
    for u, v, text in part.labels:
        msp.add_text(text, height=4.0, dxfattribs={"layer": ENGRAVE}).set_placement(
            (u, v), align=TextEntityAlignment.MIDDLE_CENTER)
    doc.saveas(path)


def write_svg(part: FlatPart, path: Path) -> None:
    """An SVG whose user unit is 1 mm (``width``/``height`` in mm), y up as in the DXF."""
    o = part.outline
    left, bottom = o.u - o.width / 2 - MARGIN, o.v - o.height / 2 - MARGIN
    width, height = o.width + 2 * MARGIN, o.height + 2 * MARGIN
    top = bottom + height

    def y(v: float) -> float:  # SVG's y grows downward
        return round(top - v + bottom, 6)

    def shape(s: Circle | Rect, layer: str) -> str:
        style = f'fill="none" stroke="{SVG_COLOURS[layer]}" stroke-width="0.1"'
        if isinstance(s, Circle):
            return f'<circle cx="{s.u:.6g}" cy="{y(s.v):.6g}" r="{s.diameter / 2:.6g}" {style}/>'
        return (f'<rect x="{s.u - s.width / 2:.6g}" y="{y(s.v + s.height / 2):.6g}" width="{s.width:.6g}" '
                f'height="{s.height:.6g}" {style}/>')

    cut = [shape(o, CUT), *(shape(h, CUT) for h in part.holes)]
    engrave = [shape(m, ENGRAVE) for m in part.marks]
    engrave += [f'<text x="{u:.6g}" y="{y(v):.6g}" font-size="4" text-anchor="middle" '
                f'fill="{SVG_COLOURS[ENGRAVE]}">{escape(text)}</text>' for u, v, text in part.labels]
    path.write_text(
        f'<?xml version="1.0" encoding="UTF-8"?>\n'
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.6g}mm" height="{height:.6g}mm" '
        f'viewBox="{left:.6g} {bottom:.6g} {width:.6g} {height:.6g}">\n'
        f'<title>{escape(part.name)}: {escape(part.material)} {part.thickness:g} mm</title>\n'
        f'<g id="{CUT}">\n' + "\n".join(cut) + '\n</g>\n'
        f'<g id="{ENGRAVE}">\n' + "\n".join(engrave) + '\n</g>\n</svg>\n')

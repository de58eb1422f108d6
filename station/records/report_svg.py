"""Top-view drawing (inline SVG) of the four wheels with their toe and camber, for the report.

Seen from above, front at the top, the station's x (right-hand wheels) to the right. Angles are
drawn exaggerated (``EXAGGERATION`` times, said on the drawing) so that tenths of a degree show;
the numbers beside each wheel are the true values. Colours: in tolerance, out of tolerance, no
figure in the spec. Signs (docs/conventions.md): toe + = toe-in (the wheel's front turned toward
the centreline), camber + = top of the wheel leaning out, thrust + = thrust line to the right.
"""

from __future__ import annotations

from html import escape

EXAGGERATION = 10.0
COLORS = {True: "#1b8a3a", False: "#c62828", None: "#6b6b6b"}
FILL = {True: "#d7f0dd", False: "#fbd9d9", None: "#e6e6e6"}
# wheel -> (x, y) of its centre in the drawing (px), and its side (+1 right, -1 left)
_W, _H = 470, 420
_CX = _W / 2
_POS = {"FL": (_CX - 70, 110, -1), "FR": (_CX + 70, 110, 1), "RL": (_CX - 70, 310, -1), "RR": (_CX + 70, 310, 1)}


MAX_DRAWN_DEG = 25.0  # larger (drawn) angles are clamped and drawn dashed: "off scale"


def _drawn(angle_deg: float | None, sign: float) -> tuple[float, bool]:
    """Screen rotation (deg) for a true angle, exaggerated and clamped; and whether it was clamped."""
    if angle_deg is None:
        return 0.0, False
    d = sign * angle_deg * EXAGGERATION
    return max(-MAX_DRAWN_DEG, min(MAX_DRAWN_DEG, d)), abs(d) > MAX_DRAWN_DEG


def _fmt(v) -> str:
    return "n/a" if v is None else f"{v:+.2f}\u00b0"


def top_view_svg(values: dict, verdicts: dict, title: str) -> str:
    """One drawing. ``values``: angle name -> deg (FL.toe, FL.camber, ..., thrust) or None;
    ``verdicts``: angle name -> True/False/None. Returns an ``<svg>`` element (text)."""
    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" class="topview" viewBox="0 0 {_W} {_H}" '
             f'width="{_W}" height="{_H}" role="img" aria-label="{escape(title)}">',
             f'<text x="{_W / 2}" y="18" text-anchor="middle" class="svg-title">{escape(title)}</text>',
             # body outline and the geometric centreline
             f'<rect x="{_CX - 50}" y="55" width="100" height="310" rx="30" fill="none" stroke="#999" stroke-width="1.5"/>',
             f'<line x1="{_CX}" y1="40" x2="{_CX}" y2="380" stroke="#999" stroke-dasharray="6 4"/>',
             f'<text x="{_CX}" y="395" text-anchor="middle" class="small">geometric centreline</text>',
             f'<polygon points="{_CX},30 {_CX - 6},42 {_CX + 6},42" fill="#999"/>',
             f'<text x="{_CX + 18}" y="40" class="small">front</text>']
    for wheel, (cx, cy, side) in _POS.items():
        toe, camber = values.get(f"{wheel}.toe"), values.get(f"{wheel}.camber")
        ok_toe, ok_camber = verdicts.get(f"{wheel}.toe"), verdicts.get(f"{wheel}.camber")
        # toe-in turns the front of a left wheel clockwise on screen (toward +x), of a right wheel
        # counter-clockwise; SVG rotate() is clockwise for positive angles (y points down)
        rot, off = _drawn(toe, -side)
        dash = ' stroke-dasharray="5 3"' if off else ""
        parts.append(f'<g transform="translate({cx},{cy}) rotate({rot:.3f})">'
                     f'<rect x="-13" y="-42" width="26" height="84" rx="6" fill="{FILL[ok_toe]}" '
                     f'stroke="{COLORS[ok_toe]}" stroke-width="2.5"{dash}/>'
                     f'<line x1="0" y1="-52" x2="0" y2="52" stroke="{COLORS[ok_toe]}" stroke-width="1"/>'
                     f'<polygon points="0,-58 -4,-50 4,-50" fill="{COLORS[ok_toe]}"/></g>')
        # camber glyph outside the wheel: the wheel seen from the front, top leaning out when +
        gx = cx + side * 50
        crot, coff = _drawn(camber, side)
        cdash = ' stroke-dasharray="4 2"' if coff else ""
        parts.append(f'<g transform="translate({gx},{cy + 22}) rotate({crot:.3f})">'
                     f'<rect x="-4" y="-40" width="8" height="40" rx="2" fill="{FILL[ok_camber]}" '
                     f'stroke="{COLORS[ok_camber]}" stroke-width="2"{cdash}/></g>'
                     f'<line x1="{gx - 12}" y1="{cy + 22}" x2="{gx + 12}" y2="{cy + 22}" stroke="#555"/>')
        tx = cx + side * 70
        anchor = "start" if side > 0 else "end"
        parts.append(f'<text x="{tx}" y="{cy - 30}" text-anchor="{anchor}" class="wheel">{wheel}</text>'
                     f'<text x="{tx}" y="{cy - 14}" text-anchor="{anchor}" fill="{COLORS[ok_toe]}">toe {_fmt(toe)}</text>'
                     f'<text x="{tx}" y="{cy + 2}" text-anchor="{anchor}" fill="{COLORS[ok_camber]}">camber {_fmt(camber)}</text>')
    thrust = values.get("thrust")
    if thrust is not None:
        ok = verdicts.get("thrust")
        trot, _ = _drawn(thrust, 1.0)
        parts.append(f'<g transform="translate({_CX},310) rotate({trot:.3f})">'
                     f'<line x1="0" y1="0" x2="0" y2="-110" stroke="{COLORS[ok]}" stroke-width="2"/>'
                     f'<polygon points="0,-120 -5,-108 5,-108" fill="{COLORS[ok]}"/></g>'
                     f'<text x="{_CX + 6}" y="255" text-anchor="start" fill="{COLORS[ok]}" class="small">'
                     f'thrust</text><text x="{_CX + 6}" y="266" text-anchor="start" fill="{COLORS[ok]}" '
                     f'class="small">{_fmt(thrust)}</text>')
    for axle, y in (("front", 172), ("rear", 352)):
        v = values.get(f"{axle}.total_toe")
        ok = verdicts.get(f"{axle}.total_toe")
        parts.append(f'<text x="{_CX}" y="{y}" text-anchor="middle" '
                     f'fill="{COLORS[ok]}" class="small">total toe {_fmt(v)}</text>')
    parts.append(f'<text x="{_W / 2}" y="{_H - 6}" text-anchor="middle" class="small">'
                 f'angles drawn {EXAGGERATION:g}\u00d7 larger (dashed: off scale); numbers are true values</text></svg>')
    return "".join(parts)

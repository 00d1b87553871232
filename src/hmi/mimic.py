"""The P&ID mimic of a site: an SVG drawing generated from its config, bound to the contract's tags.

The HMI (issue 17) shows this drawing and animates it; this module only draws it and says what
each element shows. It is pure: a :class:`~tanklab.config.SiteConfig` in, a :class:`Mimic` out
(the SVG text and the list of bindings), no I/O.

**Layout** (SVG user units; 1 unit is 1 px at 100 % zoom). Tanks stand left to right in config
order, tank k's left edge at ``x_k = MARGIN + k * PITCH``, its top at ``TANK_TOP``, every tank
``TANK_W`` wide and ``TANK_H`` tall whatever its size (a mimic shows topology and fill, not scale;
the faceplate gives the numbers). Inside each, a water rectangle anchored at the tank's bottom,
its height ``TANK_H * clamp(level / height_max, 0, 1)``: the client sets it from ``Plant.T{i}.Level``
with the element's ``data-full`` (the tank's height_max [m]). Pumps stand below the tank they feed,
a pipe up its left side into its top. A valve between tanks m and n is a bow-tie on a pipe between
their bottoms: adjacent tanks on one straight pipe, others on a lane below the tanks (one lane per
such valve, so no two pipes overlap). An outlet valve (to the drain) is on a pipe down from its
tank's bottom to the drain line at the foot of the drawing. A transmitter bubble ``LT{i}`` sits at
each tank's left (its pump's riser between them), a controller bubble ``LIC{j}`` above the tank
its PV measures, the interlock ``T{i}HH`` marker inside the tank's top right corner, the leak
marker below the tank's bottom left.

**What the client does with it** (ISA-101: everything is drawn grey; colour only for the abnormal):
every element with ``data-tag`` shows that tag's value (``data-kind`` says how: ``level`` fills,
``pump`` shows command and flow, ``opening`` draws the valve open (0..1), ``leak`` and ``fault``
mark the element when not 0 / NONE, ``trip`` marks a latched interlock); ``data-alarm`` names the
alarm condition (``T1Level``, ``T1Trip``) whose priority colours the element while it is active;
``data-faceplate`` (``loop:LIC1``, ``tank:T1``, ``pump:P1``, ``valve:V12``) is what a click opens.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from tanklab import paths
from tanklab.alarms import names as alarm_names
from tanklab.config import SiteConfig

__all__ = ["Binding", "Mimic", "mimic"]

MARGIN = 60.0
"""Left and right margin of the drawing [px]."""
PITCH = 220.0
"""Distance between two tanks' left edges [px]."""
TANK_W = 110.0
TANK_H = 220.0
TANK_TOP = 90.0
"""Top of every tank [px]; the controller bubbles are drawn above it."""
PUMP_DY = 70.0
"""Pump centre below the tanks' bottom [px]."""
PUMP_R = 16.0
LANE_DY = 30.0
"""Vertical distance between two lanes of non-adjacent connecting pipes [px]."""
BUBBLE_R = 17.0
VALVE_HALF = 10.0
"""Half the width of a valve's bow-tie [px]."""

STYLE = """
.mimic { font: 12px sans-serif; fill: #333; }
.vessel { fill: #e6e6e6; stroke: #555; stroke-width: 2; }
.water { fill: #9aa7b5; }
.pipe { fill: none; stroke: #777; stroke-width: 3; }
.signal { stroke-width: 1; stroke-dasharray: 4 3; }
.valve, .pump { fill: #d0d0d0; stroke: #555; stroke-width: 1.5; }
.bubble { fill: #fff; stroke: #555; stroke-width: 1.5; }
.marker { fill: none; stroke: none; }
.label { fill: #333; text-anchor: middle; }
"""
"""The drawing's own grey palette (ISA-101): the HMI's stylesheet adds the abnormal colours."""


@dataclass(frozen=True)
class Binding:
    """What one drawn element shows: ``tag``'s value, drawn as ``kind``."""

    element_id: str
    tag: str
    kind: str
    """``level``, ``pump_command``, ``pump_flow``, ``opening``, ``leak``, ``fault``, ``pv``, ``sp``,
    ``mode``, ``trip``."""


@dataclass(frozen=True)
class Mimic:
    """The drawing and its bindings."""

    svg: str
    bindings: tuple[Binding, ...]
    width_px: float
    height_px: float


class _Svg:
    """The element list being drawn, with the bindings the elements declare."""

    def __init__(self) -> None:
        self.parts: list[str] = []
        self.bindings: list[Binding] = []

    def el(self, tag: str, attrs: dict[str, object], text: str | None = None) -> None:
        """Add element ``tag``; ``attrs`` values are escaped, floats written with 1 decimal."""
        rendered = " ".join(f"{k.replace('_', '-')}={quoteattr(_fmt(v))}" for k, v in attrs.items())
        body = f">{_escape(text)}</{tag}>" if text is not None else "/>"
        self.parts.append(f"<{tag} {rendered}{body}")

    def bind(self, element_id: str, tag: str, kind: str) -> None:
        self.bindings.append(Binding(element_id, tag, kind))


def _fmt(v: object) -> str:
    return f"{v:.1f}" if isinstance(v, float) else str(v)


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def mimic(site: SiteConfig) -> Mimic:
    """The P&ID of ``site`` (module docstring: the layout and the element attributes)."""
    plant = site.plant
    x_of = {t.name: MARGIN + k * PITCH for k, t in enumerate(plant.tanks)}
    bottom = TANK_TOP + TANK_H
    connecting = [v for v in plant.valves if v.downstream is not None]
    order = {t.name: k for k, t in enumerate(plant.tanks)}
    lanes = [v for v in connecting if abs(order[v.upstream] - order[str(v.downstream)]) != 1]
    pump_y = bottom + PUMP_DY
    lane_top = pump_y + PUMP_R + LANE_DY
    drain_y = lane_top + LANE_DY * len(lanes) + 10.0
    width = 2 * MARGIN + (len(plant.tanks) - 1) * PITCH + TANK_W + 60.0
    height = drain_y + 30.0
    svg = _Svg()

    for tank in plant.tanks:
        _tank(svg, tank.name, x_of[tank.name], tank.height_max_m)
    for lane, valve in enumerate(lanes):
        _connecting(
            svg, valve.name, x_of[valve.upstream], x_of[str(valve.downstream)], lane_top + lane * LANE_DY
        )
    for valve in connecting:
        if valve not in lanes:
            _connecting(svg, valve.name, x_of[valve.upstream], x_of[str(valve.downstream)], None)
    for valve in plant.valves:
        if valve.downstream is None:
            _outlet(svg, valve.name, x_of[valve.upstream], drain_y)
    svg.el("path", {"class": "pipe", "d": f"M {MARGIN - 20:.1f} {drain_y:.1f} H {width - 10:.1f}"})
    svg.el("text", {"class": "label", "x": width - 30.0, "y": drain_y - 6.0}, "drain")
    for pump in plant.pumps:
        _pump(svg, pump.name, x_of[pump.feeds], pump_y)
    if site.plc is not None:
        for loop in site.plc.loops:
            _loop(svg, loop.name, x_of[f"T{loop.pv[2:]}"])
        for il in site.plc.interlocks:
            _interlock(svg, il.tank, x_of[il.tank])

    head = (
        f'<svg xmlns="http://www.w3.org/2000/svg" class="mimic" width="{width:.0f}" height="{height:.0f}" '
        f'viewBox="0 0 {width:.1f} {height:.1f}" data-site={quoteattr(site.name)}>'
    )
    body = "\n".join(svg.parts)
    return Mimic(f"{head}\n<style>{STYLE}</style>\n{body}\n</svg>\n", tuple(svg.bindings), width, height)


def _tank(svg: _Svg, name: str, x: float, height_max_m: float) -> None:
    tp, lt = paths.plant.tank(name), paths.plant.lt(name)
    face = f"tank:{name}"
    svg.el(
        "rect",
        {
            "id": f"{name}-vessel",
            "class": "vessel",
            "x": x,
            "y": TANK_TOP,
            "width": TANK_W,
            "height": TANK_H,
            "data-alarm": alarm_names.level(name),
            "data-faceplate": face,
        },
    )
    # the water: empty until the client knows the level; it grows upward from the bottom
    svg.el(
        "rect",
        {
            "id": f"{name}-water",
            "class": "water",
            "x": x + 3.0,
            "y": TANK_TOP + TANK_H - 3.0,
            "width": TANK_W - 6.0,
            "height": 0.0,
            "data-tag": tp.level,
            "data-kind": "level",
            "data-full": f"{height_max_m:g}",
            "data-bottom": f"{TANK_TOP + TANK_H - 3.0:.1f}",
            "data-span": f"{TANK_H - 6.0:.1f}",
            "data-faceplate": face,
        },
    )
    svg.bind(f"{name}-water", tp.level, "level")
    svg.el("text", {"class": "label", "x": x + TANK_W / 2, "y": TANK_TOP - 8.0}, name)
    # leak marker at the bottom left, shown while Plant.T{i}.Leak > 0
    svg.el(
        "circle",
        {
            "id": f"{name}-leak",
            "class": "marker leak",
            "cx": x + 12.0,
            "cy": TANK_TOP + TANK_H + 10.0,
            "r": 6.0,
            "data-tag": tp.leak,
            "data-kind": "leak",
            "data-faceplate": face,
        },
    )
    svg.bind(f"{name}-leak", tp.leak, "leak")
    # the transmitter bubble at the tank's left
    bx, by = x - 30.0, TANK_TOP + TANK_H * 0.6
    svg.el("path", {"class": "pipe signal", "d": f"M {bx + BUBBLE_R:.1f} {by:.1f} H {x:.1f}"})
    svg.el(
        "circle",
        {
            "id": f"{lt.name}-bubble",
            "class": "bubble",
            "cx": bx,
            "cy": by,
            "r": BUBBLE_R,
            "data-tag": lt.fault,
            "data-kind": "fault",
            "data-faceplate": face,
        },
    )
    svg.bind(f"{lt.name}-bubble", lt.fault, "fault")
    svg.el("text", {"class": "label", "x": bx, "y": by + 4.0}, lt.name)
    svg.bind(f"{lt.name}-bubble", lt.pv, "pv")


def _connecting(svg: _Svg, name: str, xa: float, xb: float, lane_y: float | None) -> None:
    bottom = TANK_TOP + TANK_H
    left, right = sorted((xa, xb))
    x0, x1 = left + TANK_W - 15.0, right + 15.0
    if lane_y is None:  # adjacent tanks: a straight pipe between their bottoms
        y = bottom - 12.0
        d = f"M {left + TANK_W:.1f} {y:.1f} H {right:.1f}"
        cx = (left + TANK_W + right) / 2
    else:  # down from each bottom to the lane, along it
        y = lane_y
        d = f"M {x0:.1f} {bottom:.1f} V {y:.1f} H {x1:.1f} V {bottom:.1f}"
        cx = left + TANK_W + (PITCH - TANK_W) / 2  # in the gap right of the left tank: clear of outlets
    svg.el("path", {"id": f"{name}-pipe", "class": "pipe", "d": d})
    _valve(svg, name, cx, y)


def _outlet(svg: _Svg, name: str, x: float, drain_y: float) -> None:
    px = x + TANK_W / 2 + 25.0
    svg.el(
        "path",
        {"id": f"{name}-pipe", "class": "pipe", "d": f"M {px:.1f} {TANK_TOP + TANK_H:.1f} V {drain_y:.1f}"},
    )
    _valve(svg, name, px, drain_y - 25.0, vertical=True)


def _valve(svg: _Svg, name: str, cx: float, cy: float, *, vertical: bool = False) -> None:
    h = VALVE_HALF
    # a bow-tie: two triangles meeting at the centre, across the pipe's direction
    corners = ((-h, -h), (h, -h), (-h, h), (h, h)) if vertical else ((-h, -h), (h, h), (h, -h), (-h, h))
    pts = " ".join(f"{cx + dx:.1f},{cy + dy:.1f}" for dx, dy in corners)
    tag = paths.plant.valve_opening(name)
    svg.el(
        "polygon",
        {
            "id": f"{name}-valve",
            "class": "valve",
            "points": pts,
            "data-tag": tag,
            "data-kind": "opening",
            "data-faceplate": f"valve:{name}",
        },
    )
    svg.bind(f"{name}-valve", tag, "opening")
    label_at = (cx + h + 16.0, cy + 4.0) if vertical else (cx, cy - h - 4.0)
    svg.el("text", {"class": "label", "x": label_at[0], "y": label_at[1]}, name)


def _pump(svg: _Svg, name: str, tank_x: float, y: float) -> None:
    pp = paths.plant.pump(name)
    cx = tank_x + TANK_W / 2
    top = TANK_TOP
    riser = tank_x - 8.0  # up the tank's left side, into its top
    svg.el(
        "path",
        {
            "id": f"{name}-pipe",
            "class": "pipe",
            "d": f"M {cx - PUMP_R:.1f} {y:.1f} H {riser:.1f} V {top - 12.0:.1f} "
            f"H {tank_x + 20.0:.1f} V {top + 8.0:.1f}",
        },
    )
    svg.el(
        "circle",
        {
            "id": f"{name}-pump",
            "class": "pump",
            "cx": cx,
            "cy": y,
            "r": PUMP_R,
            "data-tag": pp.command,
            "data-kind": "pump",
            "data-faceplate": f"pump:{name}",
        },
    )
    svg.bind(f"{name}-pump", pp.command, "pump_command")
    svg.bind(f"{name}-pump", pp.flow, "pump_flow")
    svg.el("text", {"class": "label", "x": cx, "y": y + 4.0}, name)


def _loop(svg: _Svg, name: str, tank_x: float) -> None:
    lp = paths.plc.loop(name)
    cx, cy = tank_x + TANK_W / 2, TANK_TOP - 45.0
    svg.el(
        "circle",
        {
            "id": f"{name}-bubble",
            "class": "bubble",
            "cx": cx,
            "cy": cy,
            "r": BUBBLE_R + 6.0,
            "data-tag": lp.mode,
            "data-kind": "mode",
            "data-alarm": alarm_names.pv_bad(name),
            "data-faceplate": f"loop:{name}",
        },
    )
    svg.bind(f"{name}-bubble", lp.mode, "mode")
    svg.bind(f"{name}-bubble", lp.sp, "sp")
    svg.bind(f"{name}-bubble", lp.pv, "pv")
    svg.el("text", {"class": "label", "x": cx, "y": cy + 4.0}, name)


def _interlock(svg: _Svg, tank: str, tank_x: float) -> None:
    tag = paths.plc.interlock(tank)
    svg.el(
        "rect",
        {
            "id": f"{tank}-trip",
            "class": "marker trip",
            "x": tank_x + TANK_W - 26.0,
            "y": TANK_TOP + 6.0,
            "width": 20.0,
            "height": 14.0,
            "data-tag": tag,
            "data-kind": "trip",
            "data-alarm": alarm_names.trip(tank),
            "data-faceplate": f"tank:{tank}",
        },
    )
    svg.bind(f"{tank}-trip", tag, "trip")

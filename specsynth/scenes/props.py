"""Clutter for work surfaces, placed (not dropped): what real desks and benches carry.

A dressed top keeps a free *stage area* (where the dataset's objects will be dropped; the stage
finder finds it again in the geometry) and gets, around and behind it: monitors showing a
photograph, a keyboard and a mouse, a desk lamp with its spot light, an open shelf unit of binders
and books, stacks of books, boxes, catalogue items (mugs, bottles, plants, phones, tools), cables,
and flat printed matter (pages, magazines, a board of fiducial markers with a poster in its middle)
lying everywhere, the stage area included, as under the LM-O objects. Flat printed matter is under 2 mm thick and does not collide (objects rest on the
top through it, sinking at most that far), so it never changes where a stage is; only a marker board
collides, so that the objects stand on it and the stage is found on its top.

Everything comes from one ``numpy`` generator: the same seed gives the same desk everywhere.
Coordinates: a top's local frame has ``u`` along its width and ``v`` towards its back (the wall
side), origin at its centre; :class:`Top` maps them to the world.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from ..assets.library import furniture, printed
from ..model.colour import kelvin_rgb
from .models import LightDef, SceneMaterial, SceneMesh, Transform

PAPER = 0.0002  # metres: one sheet
BOARD = 0.0008  # metres: a marker board (printed card)
BOARD_MIDDLE = 5 / 7  # the share of a board's depth (and width) inside its ring of markers (printed._board)
FLAT_STEP = 0.0003  # each flat item lies this much above the one before: no coplanar faces
ITEM_GAP = 0.02  # free space kept between placed items
SEAM_GAP = 0.03  # metres: a stage area beside the seam of two desks keeps this far from it
DESK_AREA = 1.3  # square metres: a typical desk's top (the catalogue's desks: 0.7-1.6), which the counts are for
# Catalogue items by what they are, from their names.
ITEM_GROUPS = {
    "drink": r"mug|cup\b|coffee cup|glass\b|beer bottle|wine bottle|yogurt|milk|baby bottle|plastic cup",
    "plant": r"plant|cactus|succulent|bonsai|bamboo",
    "device": r"phone|iphone|tablet|remote|camera|headphones|calculator|clock|speaker|radio|mp3|joystick|watch",
    "office": r"penbox|calendar|letter tray|ruler|scissors|text marker|tape|glasses|keys|stapler",
    "tool": r"drill|hammer|screwdriver|tool\b|scale",
    "floor": r"dustbin|recycling bin|backpack|handbag|briefcase|cardboard box|box$|basketball|soccer ball",
    "toy": r"car model|doll|teddy|toy train|wood toy|rubik|puzzle|biplane|card game|deer",
    "computer": r"laptop|ibook|printer",
}
LAMPS = ("Scopia#desk_lamp1", "Scopia#desk_lamp2", "Blend Swap CC-0#desklamp")
CABLE_COLOURS = ((0.02, 0.02, 0.02), (0.03, 0.03, 0.035), (0.85, 0.85, 0.83), (0.25, 0.25, 0.27))
# Office binders come in a few strong colours and black and white (linear RGB).
BINDER_COLOURS = ((0.45, 0.03, 0.03), (0.03, 0.09, 0.4), (0.7, 0.5, 0.02), (0.04, 0.3, 0.08), (0.6, 0.18, 0.02),
                  (0.02, 0.02, 0.02), (0.75, 0.75, 0.73), (0.25, 0.06, 0.3))
SHELF_FINISHES = ((0.8, 0.8, 0.78), (0.55, 0.4, 0.25), (0.3, 0.2, 0.12), (0.12, 0.12, 0.12), (0.6, 0.6, 0.62))
PANEL = 0.018  # metres: a shelf board's thickness
# metres: a shelf unit's back this far in from the top's back edge. A desk stands 10 mm from its wall
# and a pinboard's sheets reach 36 mm out from the wall: 30 mm keeps the two apart.
SHELF_BACK = 0.03


@dataclass(frozen=True)
class Top:
    """A rectangular work surface in the world: centre, size along its own axes, yaw of its width
    axis from world +X (degrees), height. Its back (local +v) is the side against the wall."""

    cx: float
    cy: float
    width: float
    depth: float
    yaw: float
    z: float

    def world(self, u: float, v: float) -> tuple[float, float]:
        c, s = math.cos(math.radians(self.yaw)), math.sin(math.radians(self.yaw))
        return self.cx + c * u - s * v, self.cy + s * u + c * v


@dataclass
class Dressing:
    """What a top gets: scene meshes, lights, the credits of third-party assets, and the stage
    area kept free (local u0, v0, u1, v1)."""

    meshes: list[SceneMesh] = field(default_factory=list)
    lights: list[LightDef] = field(default_factory=list)
    credits: list[dict] = field(default_factory=list)
    stage: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)


class _Layout:
    """Rectangles taken on a top (local frame), and the placing of new ones clear of them."""

    def __init__(self, top: Top, rng, keep_free):
        self.top, self.rng, self.taken = top, rng, [keep_free]

    def free(self, box) -> bool:
        u0, v0, u1, v1 = box
        w, d = self.top.width / 2, self.top.depth / 2
        if u0 < -w + 0.01 or u1 > w - 0.01 or v0 < -d + 0.01 or v1 > d - 0.01:
            return False
        return not any(u0 < b[2] + ITEM_GAP and b[0] < u1 + ITEM_GAP and v0 < b[3] + ITEM_GAP and b[1] < v1 + ITEM_GAP
                       for b in self.taken)

    def place(self, w: float, d: float, zone, tries: int = 12):
        """A spot for a ``w`` x ``d`` footprint inside ``zone`` (u0, v0, u1, v1) clear of the rest,
        taken; None when there is none."""
        zu0, zv0, zu1, zv1 = zone
        if zu1 - zu0 < w or zv1 - zv0 < d:
            return None
        for _ in range(tries):
            u = float(self.rng.uniform(zu0 + w / 2, zu1 - w / 2))
            v = float(self.rng.uniform(zv0 + d / 2, zv1 - d / 2))
            box = (u - w / 2, v - d / 2, u + w / 2, v + d / 2)
            if self.free(box):
                self.taken.append(box)
                return u, v
        return None


class _Dresser:
    """Builds one top's meshes; every item's name is unique within the scene (``prefix``)."""

    def __init__(self, top: Top, rng, cache: Path, prefix: str, layout: _Layout):
        self.top, self.rng, self.cache, self.prefix, self.layout = top, rng, cache, prefix, layout
        self.out = Dressing()
        self.flats: list[tuple[float, float, float, float]] = []  # (u, v, radius, top z) of flat items
        # Counts are for a typical desk's top: a bigger one gets more in proportion to its area
        # (the chances of things a desk has one of do not grow).
        self.per_area = 1.0

    def count(self, lo: float, hi: float, density: float) -> int:
        """How many of a thing this top carries (``_count`` for its area)."""
        return _count(self.rng, lo, hi, density * self.per_area)

    def name(self, what: str) -> str:
        return f"{self.prefix}_{what}_{len(self.out.meshes):03d}"

    def put(self, what: str, source, u: float, v: float, z: float, yaw: float = 0.0, material=None,
            collide: bool = True, scale=1.0, rotation=None) -> None:
        x, y = self.top.world(u, v)
        rot = rotation if rotation is not None else (0.0, 0.0, self.top.yaw + yaw)
        self.out.meshes.append(SceneMesh(name=self.name(what), source=source, collide=collide,
                                         material=material or SceneMaterial(),
                                         transform=Transform(translation=(x, y, z), rotation=rot, scale=scale)))

    def printed(self, kind: str) -> printed.Printed:
        p = printed.printed(self.cache, kind, int(self.rng.integers(printed.VARIANTS[kind])))
        self.out.credits += list(p.credits)
        return p

    # ------------------------------------------------------------------ flat printed matter

    def flat(self, kind: str, w: float, d: float, u: float, v: float, yaw: float, thickness: float,
             collide: bool = False) -> None:
        p = self.printed(kind)
        radius = math.hypot(w, d) / 2
        # on the highest flat item it may overlap (a bounding circle), else on the top itself
        below = [z for (fu, fv, fr, z) in self.flats if math.hypot(u - fu, v - fv) < radius + fr]
        z0 = max(below, default=self.top.z) + FLAT_STEP
        mat = SceneMaterial(texture=str(p.path), uv_scale=(1.0 / w, 1.0 / d), roughness=float(self.rng.uniform(0.5, 0.9)),
                            specular=0.3 if kind != "magazine" else 0.6)
        self.put(kind, {"box": (w, d, thickness)}, u, v, z0 + thickness / 2, yaw, mat, collide=collide)
        self.flats.append((u, v, radius, z0 + thickness))

    # ------------------------------------------------------------------ things that stand

    def monitor(self, u: float, v: float, yaw: float) -> None:
        sw = float(self.rng.uniform(0.46, 0.62))
        sh = sw * 9 / 16
        lift = float(self.rng.uniform(0.09, 0.14))
        z = self.top.z
        c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))

        def at(dv: float) -> tuple[float, float]:  # a point dv behind the monitor's centre, in its own frame
            return u - s * dv, v + c * dv

        body = SceneMaterial(base_color=(0.02, 0.02, 0.022) if self.rng.random() < 0.8 else (0.75, 0.75, 0.76),
                             roughness=0.4, specular=0.5)
        self.put("monitor_base", {"box": (0.22, 0.17, 0.012)}, *at(0.02), z + 0.006, yaw, body)
        self.put("monitor_neck", {"box": (0.05, 0.03, lift + 0.05)}, *at(0.06), z + (lift + 0.05) / 2, yaw, body)
        cz = z + lift + sh / 2 + 0.02
        self.put("monitor_panel", {"box": (sw + 0.03, 0.035, sh + 0.03)}, *at(0.03), cz, yaw, body)
        screen = self.printed("screen")
        glow = float(self.rng.uniform(0.6, 2.0))  # W/(sr m^2): about the radiance of a lit white wall
        mat = SceneMaterial(base_color=(0.02, 0.02, 0.02), roughness=0.15, specular=0.6, emission=(glow, glow, glow),
                            emission_texture=str(screen.path), uv_scale=(1.0 / sw, 1.0 / sh))
        # half a millimetre in front of the panel's face (0.03 - 0.0175 = 0.0125 behind the centre)
        self.put("monitor_screen", {"box": (sw, 0.002, sh)}, *at(0.011), cz, yaw, mat, collide=False)
        self.cable(*at(0.06), z, toward_back=True)

    def keyboard(self, u: float, v: float, yaw: float) -> None:
        p = self.printed("keyboard")
        w, d = 0.44, 0.145
        mat = SceneMaterial(texture=str(p.path), uv_scale=(1.0 / w, 1.0 / d), roughness=0.5, specular=0.4)
        self.put("keyboard", {"box": (w, d, 0.022)}, u, v, self.top.z + 0.011, yaw, mat)

    def mouse(self, u: float, v: float, yaw: float) -> None:
        colour = (0.03, 0.03, 0.03) if self.rng.random() < 0.7 else (0.85, 0.85, 0.86)
        self.put("mouse", {"cylinder": {"radius": 0.03, "height": 0.03}}, u, v, self.top.z + 0.015, yaw,
                 SceneMaterial(base_color=colour, roughness=0.3, specular=0.6), scale=(0.62, 1.0, 1.0))

    def books(self, u: float, v: float, yaw: float, upright: bool) -> None:
        n = int(self.rng.integers(2, 6 if upright else 5))
        w, d = float(self.rng.uniform(0.15, 0.23)), float(self.rng.uniform(0.21, 0.29))
        z = self.top.z
        for k in range(n):
            t = float(self.rng.uniform(0.012, 0.045))
            cover = self.printed("cover")
            mat = SceneMaterial(texture=str(cover.path), uv_scale=(1.0 / w, 1.0 / d), roughness=float(self.rng.uniform(0.35, 0.8)))
            if upright:  # spines facing the front, standing side by side along u
                off = (k - (n - 1) / 2) * 0.05
                self.put("book", {"box": (t, w, d)}, u + off, v, z + d / 2, yaw, mat)
            else:  # a pile, each book turned a little
                self.put("book", {"box": (w, d, t)}, u, v, z + t / 2, yaw + float(self.rng.uniform(-12, 12)), mat)
                z += t

    def box(self, u: float, v: float, yaw: float, size) -> None:
        p = self.printed("cardboard")
        mat = SceneMaterial(texture=str(p.path), uv_scale=(1.0 / max(size[0], size[1]), 1.0 / size[2]), roughness=0.85,
                            specular=0.2)
        self.put("cardboard", {"box": tuple(size)}, u, v, self.top.z + size[2] / 2, yaw, mat)

    def catalogue(self, item: furniture.FurnitureItem, u: float, v: float, yaw: float, what: str = "item") -> None:
        self.put(what, {"furniture": item.id}, u, v, self.top.z + 0.001, yaw)
        self.out.credits.append(item.credit)

    def lamp(self, item: furniture.FurnitureItem, u: float, v: float, target: tuple[float, float]) -> None:
        self.catalogue(item, u, v, float(self.rng.uniform(-30, 30)), what="lamp")
        x, y = self.top.world(u, v)
        tx, ty = self.top.world(*target)
        self.out.lights.append(LightDef(
            kind="spot", power=float(self.rng.uniform(12, 40)), color=kelvin_rgb(float(self.rng.uniform(2700, 4200))),
            translation=(x, y, self.top.z + item.size[2] * 0.9), look_at=(tx, ty, self.top.z),
            spot_angle=float(self.rng.uniform(70, 110)), spot_blend=0.3))

    def desk_shelf(self, u: float, v: float, w: float, d: float, h: float) -> None:
        """An open shelf unit standing at the back of the top (centre ``u``, ``v``; ``w`` x ``d`` x
        ``h``), one or two levels filled with binders and upright books: what real desks carry above
        the height of their clutter."""
        z = self.top.z
        finish = SceneMaterial(base_color=SHELF_FINISHES[int(self.rng.integers(len(SHELF_FINISHES)))],
                               roughness=float(self.rng.uniform(0.4, 0.8)), specular=0.4)
        for side in (-1, 1):  # under the top board, not through it
            self.put("shelf_side", {"box": (PANEL, d, h - PANEL)}, u + side * (w - PANEL) / 2, v, z + (h - PANEL) / 2,
                     0.0, finish)
        self.put("shelf_top", {"box": (w, d, PANEL)}, u, v, z + h - PANEL / 2, 0.0, finish)
        self.put("shelf_back", {"box": (w - 2 * PANEL, 0.008, h - PANEL)}, u, v + d / 2 - 0.004, z + (h - PANEL) / 2,
                 0.0, finish)
        levels = [(z, z + h - PANEL)]
        if h > 0.42:  # a middle board makes two levels
            mid = z + float(self.rng.uniform(0.45, 0.55)) * h
            self.put("shelf_board", {"box": (w - 2 * PANEL, d - 0.008, PANEL)}, u, v - 0.004, mid, 0.0, finish)
            levels = [(z, mid - PANEL / 2), (mid + PANEL / 2, z + h - PANEL)]
        for lo, hi in levels:
            self.shelf_row(u - w / 2 + PANEL, u + w / 2 - PANEL, v, d - 0.03, lo, hi)

    def shelf_row(self, u0: float, u1: float, v: float, d: float, lo: float, hi: float) -> None:
        """Binders and books standing side by side between ``u0`` and ``u1`` on a level from height
        ``lo`` to ``hi``, with a gap here and there."""
        room = hi - lo - 0.01
        if room < 0.12:
            return
        u = u0 + 0.005
        while True:
            binder = self.rng.random() < 0.55
            t = float(self.rng.uniform(0.04, 0.08) if binder else self.rng.uniform(0.015, 0.045))
            if u + t > u1 - 0.005:
                break
            bh = min(room, float(self.rng.uniform(0.28, 0.32) if binder else self.rng.uniform(0.17, 0.3)))
            bd = min(d, float(self.rng.uniform(0.2, 0.26) if binder else self.rng.uniform(0.13, 0.22)))
            bv = v - d / 2 + bd / 2 + 0.005 * float(self.rng.uniform(-1, 1))  # spines flush with the front
            if binder:
                colour = BINDER_COLOURS[int(self.rng.integers(len(BINDER_COLOURS)))]
                self.put("binder", {"box": (t, bd, bh)}, u + t / 2, bv, lo + bh / 2, 0.0,
                         SceneMaterial(base_color=colour, roughness=float(self.rng.uniform(0.3, 0.6)), specular=0.5))
                label = SceneMaterial(base_color=(0.8, 0.8, 0.78), roughness=0.7)
                self.put("binder_label", {"box": (t * 0.6, 0.001, bh * 0.3)}, u + t / 2, bv - bd / 2 - 0.0005,
                         lo + bh * 0.62, 0.0, label, collide=False)
            else:
                cover = self.printed("cover")
                self.put("book", {"box": (t, bd, bh)}, u + t / 2, bv, lo + bh / 2, 0.0,
                         SceneMaterial(texture=str(cover.path), uv_scale=(1.0 / bd, 1.0 / bh),
                                       roughness=float(self.rng.uniform(0.35, 0.8))))
            u += t + (float(self.rng.uniform(0.05, 0.2)) if self.rng.random() < 0.08 else 0.001)

    def cable(self, u: float, v: float, z: float, toward_back: bool = False, length: float | None = None) -> None:
        """A cable lying on the top from (u, v): to the back edge and down, or loose."""
        r = float(self.rng.uniform(0.0022, 0.0035))
        pts = [(u, v)]
        n = int(self.rng.integers(3, 6))
        step = length / n if length else float(self.rng.uniform(0.08, 0.16))
        heading = math.pi / 2 if toward_back else float(self.rng.uniform(0, 2 * math.pi))
        for _ in range(n):
            heading += float(self.rng.uniform(-0.9, 0.9))
            pu, pv = pts[-1]
            pts.append((float(np.clip(pu + step * math.cos(heading), -self.top.width / 2 + 0.01, self.top.width / 2 - 0.01)),
                        float(np.clip(pv + step * math.sin(heading), -self.top.depth / 2 + 0.01, self.top.depth / 2 - 0.01))))
        world = [(*self.top.world(a, b), z + r) for a, b in pts]
        if toward_back:
            bx, by = self.top.world(pts[-1][0], self.top.depth / 2 + 0.01)
            world += [(bx, by, z + r), (bx, by, z - 0.3)]
        colour = CABLE_COLOURS[int(self.rng.integers(len(CABLE_COLOURS)))]
        self.out.meshes.append(SceneMesh(
            name=self.name("cable"), source={"tube": {"points": world, "radius": r}}, collide=False,
            material=SceneMaterial(base_color=colour, roughness=0.45, specular=0.5)))


@lru_cache(maxsize=None)
def items(group: str) -> tuple[furniture.FurnitureItem, ...]:
    """The catalogue's items of a group (small ones; the floor's may be bigger)."""
    pat = re.compile(ITEM_GROUPS[group], re.I)
    pool = furniture.small_items() + (_floor_extras() if group == "floor" else [])
    return tuple(i for i in pool if pat.search(i.name))


def _floor_extras() -> list[furniture.FurnitureItem]:
    """Floor-standing catalogue items a little over the small-item size (bins, bags, boxes)."""
    return [i for i in furniture.catalogue() if i.category in ("Miscellaneous", "Office", "Bedroom")
            and 0.45 < max(i.size) <= 0.7 and i.elevation == 0 and not i.light and not i.door_or_window]


def stage_area(top: Top, rng, island: bool = False, seam: bool = False) -> tuple[float, float, float, float]:
    """The free rectangle for the dataset's objects: centred along the top, towards its front; on an
    island (a top worked at from all sides) in its middle, with a row of things in front of it too;
    on an island of two desks back to back (``seam`` along v = 0) beside the seam, never across it
    (a desk's top may stop short of its box: the crack would be under the objects)."""
    w = min(top.width - 0.1, max(0.45, float(rng.uniform(0.35, 0.5)) * top.width))
    if seam:
        half = top.depth / 2
        d = min(half - 0.22, max(0.32, float(rng.uniform(0.5, 0.7)) * half))
        v = (1 if rng.random() < 0.5 else -1) * (SEAM_GAP + d / 2)
    elif island:
        d = min(top.depth - 0.5, max(0.32, float(rng.uniform(0.4, 0.55)) * top.depth))
        v = float(rng.uniform(-0.1, 0.1)) * (top.depth - d)
    else:
        d = min(top.depth - 0.08, max(0.32, float(rng.uniform(0.5, 0.65)) * top.depth))
        v = -top.depth / 2 + 0.04 + d / 2
    u = float(rng.uniform(-0.15, 0.15)) * (top.width - w)
    return u - w / 2, v - d / 2, u + w / 2, v + d / 2


def dress(top: Top, rng, cache: Path, prefix: str, density: float = 1.0, board: float = 0.35,
          island: bool = False, seam: bool = False) -> Dressing:
    """Clutter on one work surface around a free stage area. ``density`` scales every count (0:
    nothing), which is for a typical desk's top: a bigger top (a bench, two desks pushed together)
    carries more in proportion to its area; ``board`` is the chance of a marker board lying under the stage area (LM-O's test
    photographs have one under every object); an ``island`` has its stage area in the middle (beside
    its ``seam``, if two desks make it) and low things in front of it as well, so that a camera from
    any side sees a crowded top beyond."""
    stage = stage_area(top, rng, island or seam, seam)
    if density <= 0:
        return Dressing(stage=stage)
    layout = _Layout(top, rng, stage)
    dr = _Dresser(top, rng, Path(cache), prefix, layout)
    dr.per_area = max(1.0, top.width * top.depth / DESK_AREA)
    dr.out.stage = stage
    _flat_layer(dr, stage, density, board)
    _back_row(dr, stage, density)
    _sides(dr, stage, density)
    if island:
        _front_row(dr, stage, density)
    for _ in range(int(round(density * dr.per_area * rng.uniform(0, 2)))):
        dr.cable(float(rng.uniform(-top.width / 2, top.width / 2)), float(rng.uniform(stage[3], top.depth / 2)), top.z)
    return dr.out


def _count(rng, lo: float, hi: float, density: float) -> int:
    return int(round(density * float(rng.uniform(lo, hi))))


PAGE, MAGAZINE = (0.21, 0.297), (0.21, 0.28)  # metres: A4, a magazine


def _paper(dr: _Dresser, area, count: int, page_share: float = 0.35, avoid=None) -> None:
    """``count`` pages and magazines with their centres in ``area`` (local u0, v0, u1, v1); with
    ``avoid`` (a rectangle), none within half a page of it (a few tries each, else left out)."""
    rng = dr.rng
    for _ in range(count):
        kind = "page" if rng.random() < page_share else "magazine"
        w, d = PAGE if kind == "page" else MAGAZINE
        for _ in range(6):
            u, v = float(rng.uniform(area[0], area[2])), float(rng.uniform(area[1], area[3]))
            if avoid is None or not (avoid[0] - 0.1 < u < avoid[2] + 0.1 and avoid[1] - 0.1 < v < avoid[3] + 0.1):
                dr.flat(kind, w, d, u, v, float(rng.uniform(-40, 40)), PAPER if kind == "page" else 0.0015)
                break


def _flat_layer(dr: _Dresser, stage, density: float, board: float) -> None:
    """Pages and magazines all over the top; with the chance ``board``, a marker board under the
    stage area as in LM-O's photographs: lying on magazines that show round its edges, with a
    poster covering its middle and sometimes an open magazine on that, under the objects. Without a
    board, half the paper lies on or over the stage area (objects stand on paper on real desks)."""
    top, rng = dr.top, dr.rng
    whole = (-top.width / 2 + 0.12, -top.depth / 2 + 0.12, top.width / 2 - 0.12, top.depth / 2 - 0.12)
    n = dr.count(4, 10, density)
    if rng.random() >= board:
        _paper(dr, stage, n // 2)
        _paper(dr, whole, n - n // 2)
        return
    aspect = printed.SIZES["board"][1] / printed.SIZES["board"][0]
    w = min(max(float(rng.uniform(0.55, 0.8)), stage[2] - stage[0] + 0.12), top.width - 0.2, (top.depth - 0.2) / aspect)
    d = w * aspect
    yaw = float(rng.uniform(-15, 15))
    c, s_ = math.cos(math.radians(yaw)), abs(math.sin(math.radians(yaw)))
    hu, hv = (w * c + d * s_) / 2 + 0.02, (w * s_ + d * c) / 2 + 0.02  # the turned board's half extents
    # On the top, never over its edge (a collider in the air would be a stage in the air).
    cu = float(np.clip((stage[0] + stage[2]) / 2, -top.width / 2 + hu, max(-top.width / 2 + hu, top.width / 2 - hu)))
    cv = float(np.clip((stage[1] + stage[3]) / 2, -top.depth / 2 + hv, max(-top.depth / 2 + hv, top.depth / 2 - hv)))
    for su, sv in ((1, 0), (-1, 0), (0, 1), (0, -1))[: int(rng.integers(1, 5))]:  # half out from under an edge
        u, v = cu + su * (w / 2 + float(rng.uniform(-0.05, 0.05))), cv + sv * (d / 2 + float(rng.uniform(-0.05, 0.05)))
        dr.flat("magazine", *MAGAZINE, u + sv * float(rng.uniform(-0.15, 0.15)), v + su * float(rng.uniform(-0.1, 0.1)),
                float(rng.uniform(-40, 40)), 0.0015)
    # The board collides: objects stand on it (the stage is found on its top), not sunk in paper.
    dr.flat("board", w, d, cu, cv, yaw, BOARD, collide=True)
    # Its free middle (7 x 5 of its 9 x 7 cells) covered by a poster, turned to fit, as the LM-O objects
    # stand on one; sometimes an open magazine on that.
    pw, ph = printed.SIZES["poster"]
    across = BOARD_MIDDLE * d * 0.98
    dr.flat("poster", across, across * ph / pw, cu, cv, yaw + 90.0, PAPER)
    if rng.random() < 0.3:
        dr.flat("magazine", *MAGAZINE, cu + float(rng.uniform(-0.1, 0.1)) * w, cv + float(rng.uniform(-0.1, 0.1)) * d,
                float(rng.uniform(-30, 30)), PAPER)
    _paper(dr, whole, n, avoid=(cu - w / 2, cv - d / 2, cu + w / 2, cv + d / 2))


def _shelf(dr: _Dresser, stage, density: float) -> None:
    """With a chance that grows with ``density``, an open shelf unit of binders and books against the
    back edge of the top, beside or behind where the monitors stand."""
    top, rng, lay = dr.top, dr.rng, dr.layout
    d = min(0.3, top.depth / 2 - SHELF_BACK - stage[3] - ITEM_GAP - 0.005)
    w = min(float(rng.uniform(0.6, 1.1)), top.width - 0.3)
    if rng.random() >= 0.45 * density or d < 0.16:
        return
    h = float(rng.uniform(0.3, 0.7))
    v = top.depth / 2 - SHELF_BACK - d / 2
    while w >= 0.4:  # narrower where the monitors leave less room
        for _ in range(6):
            u = float(rng.uniform(-top.width / 2 + w / 2 + 0.012, top.width / 2 - w / 2 - 0.012))
            box = (u - w / 2, v - d / 2, u + w / 2, v + d / 2)
            if lay.free(box):
                lay.taken.append(box)
                dr.desk_shelf(u, v, w, d, h)
                return
        w *= 0.8


def _back_row(dr: _Dresser, stage, density: float) -> None:
    """Behind the stage area: monitors, a lamp, a shelf unit, books, boxes, plants."""
    top, rng, lay = dr.top, dr.rng, dr.layout
    back = (-top.width / 2, stage[3], top.width / 2, top.depth / 2)
    for _ in range(max(1, dr.count(0.8, 2.2, density))):
        spot = lay.place(0.62, 0.2, back)
        if spot is not None:
            dr.monitor(spot[0], spot[1], float(rng.uniform(-15, 15)))
    if rng.random() < min(1.0, 0.8 * density):
        lamp = furniture.find(LAMPS[int(rng.integers(len(LAMPS)))])
        reach = float(np.hypot(lamp.size[0], lamp.size[1]))  # its arm, at any turn: never over the stage
        spot = lay.place(reach, reach, back)
        if spot is not None:
            dr.lamp(lamp, spot[0], spot[1], ((stage[0] + stage[2]) / 2, (stage[1] + stage[3]) / 2))
    _shelf(dr, stage, density)
    for _ in range(dr.count(1, 3, density)):
        upright = rng.random() < 0.5
        spot = lay.place(0.26 if upright else 0.26, 0.3, back)
        if spot is not None:
            dr.books(spot[0], spot[1], float(rng.uniform(-10, 10)), upright)
    for _ in range(dr.count(0, 1.6, density)):
        size = (float(rng.uniform(0.15, 0.35)), float(rng.uniform(0.12, 0.28)), float(rng.uniform(0.08, 0.25)))
        spot = lay.place(max(size[:2]), max(size[:2]), back)
        if spot is not None:
            dr.box(spot[0], spot[1], float(rng.uniform(-20, 20)), size)
    _catalogue_items(dr, back, ("plant", "device", "drink", "toy", "computer"), dr.count(2, 5, density))


def _sides(dr: _Dresser, stage, density: float) -> None:
    """Left and right of the stage area: keyboard and mouse, mugs, phones, tools, books."""
    top, rng, lay = dr.top, dr.rng, dr.layout
    zones = [(-top.width / 2, -top.depth / 2, stage[0], top.depth / 2), (stage[2], -top.depth / 2, top.width / 2, top.depth / 2)]
    if rng.random() < min(1.0, 0.8 * density):
        zone = zones[int(rng.integers(2))]
        spot = lay.place(0.46, 0.16, zone)
        if spot is not None:
            yaw = float(rng.uniform(-12, 12))
            dr.keyboard(spot[0], spot[1], yaw)
            mspot = lay.place(0.08, 0.1, (spot[0] + 0.2, spot[1] - 0.15, spot[0] + 0.45, spot[1] + 0.15))
            if mspot is not None:
                dr.mouse(mspot[0], mspot[1], yaw + float(rng.uniform(-20, 20)))
    for zone in zones:
        _catalogue_items(dr, zone, ("drink", "office", "device", "tool", "plant", "toy"), dr.count(2, 5, density))
        if rng.random() < 0.4 * density:
            spot = lay.place(0.26, 0.3, zone)
            if spot is not None:
                dr.books(spot[0], spot[1], float(rng.uniform(-25, 25)), upright=False)


def _front_row(dr: _Dresser, stage, density: float) -> None:
    """Straight in front of an island's stage area: only low things (a keyboard, mugs, phones, tools,
    flat books), which a camera on that side looks over rather than at."""
    top, rng, lay = dr.top, dr.rng, dr.layout
    zone = (stage[0], -top.depth / 2, stage[2], stage[1])  # the corners are the sides' (_sides)
    if rng.random() < 0.5 * density:
        spot = lay.place(0.46, 0.16, zone)
        if spot is not None:
            dr.keyboard(spot[0], spot[1], float(rng.uniform(-12, 12)))
    _catalogue_items(dr, zone, ("drink", "office", "device", "tool"), dr.count(2, 5, density))
    if rng.random() < 0.5 * density:
        spot = lay.place(0.26, 0.3, zone)
        if spot is not None:
            dr.books(spot[0], spot[1], float(rng.uniform(-25, 25)), upright=False)


def _catalogue_items(dr: _Dresser, zone, groups: tuple[str, ...], n: int) -> None:
    for _ in range(n):
        pool = items(groups[int(dr.rng.integers(len(groups)))])
        if not pool:
            continue
        item = pool[int(dr.rng.integers(len(pool)))]
        r = 0.5 * float(np.hypot(item.size[0], item.size[1]))  # any yaw fits in this circle
        spot = dr.layout.place(2 * r, 2 * r, zone)
        if spot is not None:
            dr.catalogue(item, spot[0], spot[1], float(dr.rng.uniform(0, 360)))


def floor_items(rng, free_spots, density: float) -> list[tuple[furniture.FurnitureItem, float, float, float]]:
    """Bins, bags and boxes for the floor: (item, x, y, yaw) at some of ``free_spots`` (x, y)."""
    pool = items("floor")
    out = []
    for x, y in free_spots[: _count(rng, 1, 4, density)]:
        if pool:
            out.append((pool[int(rng.integers(len(pool)))], x, y, float(rng.uniform(0, 360))))
    return out

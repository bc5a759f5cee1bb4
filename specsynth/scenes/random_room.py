"""``random_room``: a furnished room drawn from a seed, a new one for every arrangement.

The room (size, floor/wall/ceiling textures, a window with an HDRI sky behind it, lights) and its
furniture (Sweet Home 3D library models of the room's kind, against the walls facing in, plus a
table or two in the free middle, never overlapping) all come from one ``numpy`` generator seeded
by the arrangement, so the same seed gives the same room on every machine. Stages are found on
what was placed (table tops, shelves, counters, the free floor), by :mod:`.autostage`.

Units: metres; the interior spans x in [-W/2, W/2], y in [-D/2, D/2], floor at z = 0.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..assets.library import furniture, pmndrs, printed, textures
from ..assets.library import pictures as picture_library
from ..assets.resolve import mean_linear_colour
from ..model.colour import kelvin_rgb, srgb_to_linear
from . import props
from .models import FocusArea, LightDef, SceneFile, SceneMaterial, SceneMesh, Transform, World

# 2: painted walls, rugs, daylight-to-warm lights, furniture re-dressed. 3: room parameters,
# workshop and shop kinds, a lamp per room, fixed furnished rooms. 4: clutter on furniture tops.
# 5: framed photographs on the walls. 6: dressed work surfaces (props), office_desk and lab kinds, floor
# items, daylight through the window, ceiling panels, surface detail (normal maps, roughness, tints). 7: more
# magazines than pages, a stronger desk lamp, the panel over the desk the brightest. 8: a flat item lies
# on the flat items it overlaps, not on every one placed before it. 9: relief and roughness on a grid of 0.05.
# 10: a marker board (room.boards) lies on magazines with magazines open on it, and collides; toys and laptops on
# desks; a pinboard with pinned sheets above a desk against a wall. 11: an open shelf unit of binders and books at
# the back of a dressed top. 12: pinboards hang lower (where a camera looking at the desk sees the wall), with
# more sheets; a poster covers the marker board's middle. 13: the shelf unit stands clear of the pinboard.
# 14: islands (room.islands): the work surface in the middle of the room, dressed on all sides. 15: a top
# bigger than a typical desk's (a bench, an island of two desks) is dressed in proportion to its area.
# 16: desk and bench tops finished as office furniture is (DESK_FINISHES), not in any wood of the library;
# offices and labs in office colours (OFFICE_PAINTS, OFFICE_FLOORS, neutral carpets, no rug).
GENERATOR_VERSION = 16
# Kind -> catalogue categories, and (for kinds no category matches) the models' names that belong.
ROOM_KINDS: dict[str, tuple[tuple[str, ...], str | None]] = {
    "living_room": (("Living room",), None),
    "kitchen": (("Kitchen",), None),
    "office": (("Office",), None),
    "bedroom": (("Bedroom",), None),
    "workshop": (("Miscellaneous", "Office"), r"workbench|ladder|crate|barrel|box|pallet|trunck|logs|extinguisher|"
                 r"recycling|furnace|mower|radiator|water heater|technical table|filing cabinet|safe|wooden table"),
    "shop": (("Living room", "Kitchen", "Office", "Bedroom"), r"bookcase|shel|cabinet|chest|dresser|counter|rack|"
             r"desk table|wooden table|freezer"),
    "office_desk": (("Office", "Living room"), r"desk|table|bookcase|shel|filing|cabinet|chair|armchair|plant|sofa"),
    "lab": (("Office", "Miscellaneous", "Kitchen"), r"technical table|workbench|filing cabinet|bookcase|shel|cabinet|"
            r"crate|box|barrel|recycling|extinguisher|stool|water heater|radiator|chair"),
}
# Kinds whose room is built around one work surface, the first piece placed (against the window wall
# when it fits): the catalogue models that can be it.
WORKTOPS: dict[str, str] = {
    "office_desk": r"^(Blend Swap CC-0#lbDesk|Blend Swap CC-BY#simpleDesk|Blend Swap CC-BY#officeTable|"
                   r"Blend Swap CC-BY#biurko3|Scopia#wooden_office_pear_table_rect|Scopia#wooden_table_office|"
                   r"Scopia#table4|Scopia#black_table|Kator Legaz#folding-table)$",
    "lab": r"^(Blend Swap CC-0#technicalTable1|Kator Legaz#folding-table|Scopia#table-on-trestles|"
           r"Scopia#table-with-leaning-feet|Scopia#wooden_office_pear_table_rect)$",
}


@dataclass(frozen=True)
class RoomParams:
    """What a room is drawn from (metres; counts are pieces of furniture)."""

    kinds: tuple[str, ...] = tuple(ROOM_KINDS)[:4]
    width: tuple[float, float] = (3.6, 6.0)
    depth: tuple[float, float] = (3.2, 5.0)
    height: tuple[float, float] = (2.5, 2.9)
    wall_pieces: tuple[int, int] = (6, 10)
    middle_pieces: tuple[int, int] = (1, 2)
    categories: tuple[str, ...] | None = None  # catalogue categories instead of the kind's
    clutter: tuple[int, int] = (1, 3)  # small catalogue items on each furniture top that is no work surface
    pictures: tuple[int, int] = (1, 3)  # framed photographs on the walls
    density: float = 1.0  # how much stands on work surfaces and the floor (props.dress); 0: nothing
    sun: float = 0.6  # chance of direct sunlight through the window
    boards: float = 0.35  # chance of a marker board under a dressed desk's stage area
    islands: float = 0.0  # chance that the work surface stands in the middle, worked at from all sides
OUTDOOR_HDRIS = ("city", "courtyard", "forest", "sunrise", "sunset")
# Wall paints (linear RGB multipliers of the plaster texture) and rug dyes: real rooms are not all beige.
PAINTS = ((1.0, 1.0, 1.0), (0.95, 0.93, 0.85), (0.62, 0.75, 0.88), (0.66, 0.8, 0.62), (0.92, 0.62, 0.48),
          (0.95, 0.85, 0.5), (0.7, 0.7, 0.72), (0.85, 0.66, 0.8), (0.45, 0.6, 0.7))
# Offices and labs: walls white to pale grey, floors in neutral woods and tiles or dark grey carpet tiles,
# as offices are (and the LM-O test photographs' office is); their furniture's woods are the same
# few (no blue, green, red or varnished orange wood). Their colour is in the things on the desks.
OFFICE_KINDS = ("office", "office_desk", "lab")
OFFICE_PAINTS = ((1.0, 1.0, 1.0), (0.95, 0.93, 0.85), (0.88, 0.9, 0.92), (0.8, 0.8, 0.8), (0.92, 0.9, 0.84))
OFFICE_FLOORS = ("gray-woodgrain", "light-gray-floor-tile", "dark-wood", "light-wood")
OFFICE_WALLS = ("cream-plaster", "gray-plaster", "light-gray-plaster", "pink-plaster", "white-bricks", "white-plaster")
CARPETS = ((0.1, 0.1, 0.1), (0.16, 0.16, 0.17), (0.22, 0.22, 0.22), (0.12, 0.13, 0.15), (0.2, 0.19, 0.18))
DYES = ((0.6, 0.12, 0.1), (0.1, 0.25, 0.55), (0.15, 0.4, 0.2), (0.55, 0.45, 0.1), (0.4, 0.15, 0.45),
        (0.08, 0.35, 0.4), (0.5, 0.3, 0.2), (0.7, 0.55, 0.4))
# Desk and bench tops: the mean colour (sRGB) of laminates and light woods as offices and labs have them
# (the LM-O test photographs' desk is light beige wood), now and then grey or anthracite. Grain comes
# from a light wood texture of the library; red, blue and varnished woods are floors, not desks.
DESK_FINISHES = ((0.84, 0.77, 0.63), (0.80, 0.68, 0.52), (0.87, 0.81, 0.70), (0.76, 0.74, 0.70),
                 (0.88, 0.88, 0.86), (0.62, 0.61, 0.58), (0.30, 0.30, 0.31))
DESK_GRAIN = ("gray-woodgrain", "light-wood")
NOT_TOP_WORDS = re.compile(r"metal|chrome|alum|steel|brushed|rubber|lock|handle|leg|glass", re.I)
WALL = 0.1  # wall thickness, metres
GAP = 0.06  # free space kept between pieces of furniture
REDRESS = 0.75  # probability that a plain wood-like or fabric-like material gets a texture


@dataclass(frozen=True)
class Placed:
    item: furniture.FurnitureItem
    x: float
    y: float
    yaw: float  # degrees; the front faces -Y at 0
    footprint: tuple[float, float, float, float]  # x0, y0, x1, y1
    middle: bool = False  # stands free in the room (not against a wall)
    island: tuple[float, float, float, float] | None = None  # the shared top (x, y, w, d) of desks pushed together

    @property
    def centre(self) -> tuple[float, float]:
        return (self.island[0], self.island[1]) if self.island else (self.x, self.y)


def _fits(items, room_w: float, room_d: float, room_h: float) -> list[furniture.FurnitureItem]:
    return [i for i in items if not i.door_or_window and not i.light and i.elevation == 0
            and max(i.size[0], i.size[1]) < 0.6 * min(room_w, room_d) and 0.3 < i.size[2] < room_h - 0.3
            and min(i.size[0], i.size[1]) > 0.2]


def _overlaps(fp, placed: list[Placed]) -> bool:
    x0, y0, x1, y1 = fp
    return any(x0 < q.footprint[2] + GAP and q.footprint[0] < x1 + GAP and y0 < q.footprint[3] + GAP
               and q.footprint[1] < y1 + GAP for q in placed)


def _against_wall(rng, item, W, D, window) -> tuple[float, float, float, tuple]:
    """A position with the piece's back to a random wall, front facing into the room."""
    w, d, _ = item.size
    wall = int(rng.integers(4))
    if wall in (0, 1):  # north (y = +D/2, faces -y: yaw 0), south (faces +y: yaw 180)
        x = float(rng.uniform(-W / 2 + w / 2, W / 2 - w / 2))
        y = D / 2 - d / 2 - 0.01 if wall == 0 else -D / 2 + d / 2 + 0.01
        yaw, fp = (0.0 if wall == 0 else 180.0), (x - w / 2, y - d / 2, x + w / 2, y + d / 2)
    else:  # east (x = +W/2, faces -x: yaw -90), west (faces +x: yaw 90)
        y = float(rng.uniform(-D / 2 + w / 2, D / 2 - w / 2))
        x = W / 2 - d / 2 - 0.01 if wall == 2 else -W / 2 + d / 2 + 0.01
        yaw, fp = (-90.0 if wall == 2 else 90.0), (x - d / 2, y - w / 2, x + d / 2, y + w / 2)
    if wall == 0 and item.size[2] > window[2] and fp[0] < window[1] and window[0] < fp[2]:
        return None  # a tall piece would block the window
    return x, y, yaw, fp


def _worktop(rng, worktops: list[furniture.FurnitureItem], W: float, D: float, window) -> Placed | None:
    """The room's work surface against the window wall, under the window when it fits there (daylight
    on the desk, as in an office), else against any wall."""
    for k in range(40):
        item = worktops[int(rng.integers(len(worktops)))]
        w, d = item.size[:2]
        if w > W - 0.2:
            continue
        if k < 20:
            x = float(np.clip((window[0] + window[1]) / 2 + rng.uniform(-0.4, 0.4), -W / 2 + w / 2, W / 2 - w / 2))
            y = D / 2 - d / 2 - 0.01
            return Placed(item, x, y, 0.0, (x - w / 2, y - d / 2, x + w / 2, y + d / 2))
        pos = _against_wall(rng, item, W, D, window)
        if pos is not None:
            return Placed(item, *pos)
    return None


ISLAND_CLEAR = 0.8  # metres of free floor round an island: where the cameras stand


def _island(rng, worktops: list[furniture.FurnitureItem], W: float, D: float) -> list[Placed]:
    """The work surface in the middle of the room, as a lab bench or two desks pushed together back to
    back (one top about 1.2-1.8 m deep) -> its pieces, each knowing the shared top; [] when none fits."""
    for _ in range(20):
        item = worktops[int(rng.integers(len(worktops)))]
        w, d = item.size[:2]
        pair = d < 1.0
        depth = 2 * d if pair else d
        if w > W - 2 * ISLAND_CLEAR or depth > D - 2 * ISLAND_CLEAR:
            continue
        x = float(rng.uniform(-1, 1)) * (W / 2 - ISLAND_CLEAR - w / 2) * 0.5
        y = float(rng.uniform(-1, 1)) * (D / 2 - ISLAND_CLEAR - depth / 2) * 0.5
        top = (x, y, w, depth)
        if not pair:
            return [Placed(item, x, y, 0.0, (x - w / 2, y - d / 2, x + w / 2, y + d / 2), middle=True, island=top)]
        # Back to back, so that each desk's front (where its worker sits) faces out of the island.
        return [Placed(item, x, y + s * d / 2, yaw, (x - w / 2, y + min(0, s) * d, x + w / 2, y + max(0, s) * d),
                       middle=True, island=top) for s, yaw in ((-1, 0.0), (1, 180.0))]
    return []


def island_keep_out(placed: list[Placed]) -> list[Placed]:
    """The island's pieces grown so that anything kept clear of them (``_overlaps`` adds GAP) stands
    ISLAND_CLEAR away: the floor round an island stays free, for the cameras that stand there."""
    c = ISLAND_CLEAR - GAP
    return [replace(p, footprint=(p.footprint[0] - c, p.footprint[1] - c, p.footprint[2] + c, p.footprint[3] + c))
            for p in placed if p.island is not None]


def furnish(rng, items, W, D, window, n_wall: int, n_middle: int,
            worktops: list[furniture.FurnitureItem] | None = None, island: float = 0.0) -> list[Placed]:
    placed: list[Placed] = []
    if worktops and island > 0 and rng.random() < island:
        placed += _island(rng, worktops, W, D)
    keep_out = island_keep_out(placed)
    if worktops and not placed:
        first = _worktop(rng, worktops, W, D, window)
        if first is not None:
            placed.append(first)
    surfaces = [i for i in items if i.drop_on_top is not None and 0.35 < i.drop_on_top < 1.3]
    others = [i for i in items if i not in surfaces]
    for k in range(n_wall):
        pool = surfaces if (k % 2 == 0 or not others) else others  # half of them carry a stage
        for _ in range(40):
            item = pool[int(rng.integers(len(pool)))]
            pos = _against_wall(rng, item, W, D, window)
            if pos is not None and not _overlaps(pos[3], placed + keep_out):
                placed.append(Placed(item, *pos))
                break
    tables = [i for i in surfaces if i.size[0] > 0.5 and i.size[1] > 0.4]
    for _ in range(n_middle if tables else 0):
        for _ in range(40):
            item = tables[int(rng.integers(len(tables)))]
            turn = bool(rng.integers(2))
            w, d = (item.size[1], item.size[0]) if turn else item.size[:2]
            x = float(rng.uniform(-W / 2 + w / 2 + 0.5, W / 2 - w / 2 - 0.5)) if W > w + 1.0 else 0.0
            y = float(rng.uniform(-D / 2 + d / 2 + 0.5, D / 2 - d / 2 - 0.5)) if D > d + 1.0 else 0.0
            fp = (x - w / 2, y - d / 2, x + w / 2, y + d / 2)
            if not _overlaps(fp, placed + keep_out):
                placed.append(Placed(item, x, y, 90.0 if turn else 0.0, fp, middle=True))
                break
    return placed


TOP_WORDS = re.compile(r"table|desk|cabinet|chest|dresser|counter|sideboard|drawer|commode|buffet|worktop|"
                       r"sink|dishwasher|washing machine|bench|crate|trunk", re.I)


def open_top(item: furniture.FurnitureItem) -> float | None:
    """Height of the open top things can stand on (tables, counters, cabinets), else None: a chair's
    seat or a shelf board has parts above it, and a model without a catalogue surface is only
    trusted to have a flat top when its name says so."""
    top = item.drop_on_top
    if top is None or top < 0:
        top = item.size[2] if TOP_WORDS.search(item.name) and not re.search(r"chair", item.name, re.I) else None
    if top is None or top < 0.3 or item.size[2] - top > 0.08:
        return None
    return float(top)


def is_worktop(item: furniture.FurnitureItem) -> bool:
    """A desk, table or bench top to work at: dressed by :mod:`.props` rather than given a few items."""
    top = open_top(item)
    return top is not None and 0.6 <= top <= 1.0 and item.size[0] >= 0.9 and item.size[1] >= 0.5


def dress_worktops(rng, placed: list[Placed], cache: Path, density: float, boards: float = 0.35):
    """Every work surface dressed -> (meshes, lights, credits, focus areas: its stage area)."""
    meshes, lights, credits, focus = [], [], [], []
    dressed = set()
    for k, p in enumerate(placed):
        if not is_worktop(p.item) or (p.island is not None and p.island in dressed):
            continue
        # A piece against a wall has its back there; one in the middle is worked at from either side.
        yaw = p.yaw if not p.middle else p.yaw + 180.0 * int(rng.integers(2))
        x, y, w, depth = p.island or (p.x, p.y, p.item.size[0], p.item.size[1])
        top = props.Top(x, y, w, depth, yaw, float(open_top(p.item)))
        pair = p.island is not None and sum(q.island == p.island for q in placed) == 2
        d = props.dress(top, rng, cache, f"desk{k:02d}", density, board=boards, island=p.island is not None, seam=pair)
        if p.island is not None:
            dressed.add(p.island)
        meshes += d.meshes
        lights += d.lights
        credits += d.credits
        u0, v0, u1, v1 = d.stage
        focus.append(FocusArea(polygon=[top.world(u, v) for u, v in ((u0, v0), (u1, v0), (u1, v1), (u0, v1))],
                               height=top.z))
    return meshes, lights, credits, focus


def clutter(rng, placed: list[Placed], items: list[furniture.FurnitureItem], per_top: tuple[int, int]) -> list[SceneMesh]:
    """Small items standing on the tops of the placed furniture, none overlapping, each inside one
    half of its top (shrunk by a margin); stages are then found on what stays free around them."""
    out: list[SceneMesh] = []
    for p in placed:
        top = open_top(p.item)
        if top is None or not items or per_top[1] == 0 or is_worktop(p.item):
            continue
        x0, y0, x1, y1 = p.footprint
        # Clutter keeps to one half of the top (split along its long side): the other half stays a stage.
        if x1 - x0 >= y1 - y0:
            x0, x1 = (x0, (x0 + x1) / 2) if rng.random() < 0.5 else ((x0 + x1) / 2, x1)
        else:
            y0, y1 = (y0, (y0 + y1) / 2) if rng.random() < 0.5 else ((y0 + y1) / 2, y1)
        taken: list[tuple[float, float, float, float]] = []
        fitting = [i for i in items if float(np.hypot(i.size[0], i.size[1])) + 0.1 < min(x1 - x0, y1 - y0)]
        for _ in range(int(rng.integers(per_top[0], per_top[1] + 1)) if fitting else 0):
            for _ in range(10):  # a few tries for a free spot
                item = fitting[int(rng.integers(len(fitting)))]
                r = 0.5 * float(np.hypot(item.size[0], item.size[1]))  # any yaw fits in this circle
                x = float(rng.uniform(x0 + r + 0.05, x1 - r - 0.05))
                y = float(rng.uniform(y0 + r + 0.05, y1 - r - 0.05))
                box = (x - r, y - r, x + r, y + r)
                if not any(box[0] < q[2] and q[0] < box[2] and box[1] < q[3] and q[1] < box[3] for q in taken):
                    break
            else:
                continue
            taken.append(box)
            yaw = float(rng.uniform(0, 360))
            out.append(SceneMesh(name=f"clutter_{len(out):02d}", source={"furniture": item.id},
                                 transform=Transform(translation=(x, y, float(top) + 0.001), rotation=(0.0, 0.0, yaw))))
    return out


def _tex(rng, options: list, what: str) -> textures.SurfaceTexture:
    if not options:
        raise textures.TextureLibraryError(f"random_room: no {what} textures installed")
    return options[int(rng.integers(len(options)))]


def _box(name: str, size, at, material: SceneMaterial, collide: bool = True) -> SceneMesh:
    return SceneMesh(name=name, source={"box": tuple(float(s) for s in size)},
                     transform=Transform(translation=tuple(float(a) for a in at)), material=material, collide=collide)


def _walls(W: float, D: float, H: float, window, mat: SceneMaterial) -> list[SceneMesh]:
    """Four walls outside the interior; the north wall has the window opening (x0..x1, sill..top)."""
    x0, x1, sill, top = window
    t = WALL
    out = [
        _box("wall_south", (W + 2 * t, t, H), (0, -D / 2 - t / 2, H / 2), mat),
        _box("wall_east", (t, D, H), (W / 2 + t / 2, 0, H / 2), mat),
        _box("wall_west", (t, D, H), (-W / 2 - t / 2, 0, H / 2), mat),
        _box("wall_north_left", (x0 + W / 2 + t, t, H), ((x0 - W / 2 - t) / 2, D / 2 + t / 2, H / 2), mat),
        _box("wall_north_right", (W / 2 + t - x1, t, H), ((x1 + W / 2 + t) / 2, D / 2 + t / 2, H / 2), mat),
        _box("wall_north_below", (x1 - x0, t, sill), ((x0 + x1) / 2, D / 2 + t / 2, sill / 2), mat),
        _box("wall_north_above", (x1 - x0, t, H - top), ((x0 + x1) / 2, D / 2 + t / 2, (H + top) / 2), mat),
    ]
    return out


FABRIC_WORDS = ("fabric", "cloth", "sheet", "bed", "cushion", "couch", "sofa", "pillow", "blanket", "mattress",
                "textile", "seat", "tela", "colchon", "cojin")
WOOD_WORDS = ("wood", "table", "top", "desk", "shelf", "cabinet", "drawer", "madera", "worktop")


def redress(rng, item: furniture.FurnitureItem, cache: Path, woods: list, felt) -> tuple[dict, list[dict]]:
    """Domain randomisation of one piece: its plain wood-like and fabric-like materials (no texture,
    or one whose file the model lacks), told apart by their names, get a wood texture or a dyed
    felt, each with probability ``REDRESS``.
    -> (``materials:`` overrides by name, credits of the textures used)."""
    from ..assets.meshfiles import obj as obj_reader

    overrides, credits = {}, []
    mats = obj_reader.materials_of(furniture.extract(item, cache))
    for name, (mat, lib) in sorted(mats.items()):
        low = name.lower()
        textured = bool(mat.map_kd) and obj_reader.texture_path(lib, mat.map_kd).is_file()  # some name lost files
        if textured or rng.random() < 1.0 - REDRESS:
            continue
        if felt is not None and any(w in low for w in FABRIC_WORDS):
            dye = DYES[int(rng.integers(len(DYES)))]
            overrides[name] = SceneMaterial(texture=str(felt.path), base_color=dye, uv_scale=40.0, roughness=0.95, specular=0.2,
                                            **_relief(rng, cache, "fabric", (0.2, 0.6)))
            credits.append(felt.credit)
        elif woods and any(w in low for w in WOOD_WORDS):
            t = woods[int(rng.integers(len(woods)))]
            overrides[name] = SceneMaterial(texture=str(t.path), uv_scale=1.0, roughness=_step(rng.uniform(0.3, 0.6)),
                                            base_color=_tint(rng), **_relief(rng, cache, "wood", (0.15, 0.5)))
            credits.append(t.credit)
    return overrides, credits


def _rug(rng, W: float, D: float, felt) -> list[SceneMesh]:
    """Half the rooms get a dyed felt rug (a thin box: objects may land on it)."""
    if felt is None or rng.random() < 0.5:
        return []
    w, d = float(rng.uniform(1.2, min(2.4, W - 1.0))), float(rng.uniform(0.9, min(1.8, D - 1.0)))
    dye = DYES[int(rng.integers(len(DYES)))]
    mat = SceneMaterial(texture=str(felt.path), base_color=dye, uv_scale=1.0 / felt.tile, roughness=0.95, specular=0.2)
    return [_box("rug", (w, d, 0.01), (float(rng.uniform(-W / 4, W / 4)), float(rng.uniform(-D / 4, D / 4)), 0.005), mat)]


def kind_items(kind: str, categories: tuple[str, ...] | None = None) -> list[furniture.FurnitureItem]:
    cats, names = ROOM_KINDS[kind]
    if categories is not None:
        cats, names = categories, None
    pat = re.compile(names, re.I) if names else None
    return [i for i in furniture.catalogue() if i.category in cats and (pat is None or pat.search(i.name))]


def _lamp(rng, placed: list[Placed], W: float, D: float, small: list[SceneMesh]) -> LightDef:
    """A warm lamp: above a piece of furniture and what stands on it (as a table or floor lamp
    would be; a light inside a cup casts room-sized shadows), else a corner."""
    if placed:
        p = placed[int(rng.integers(len(placed)))]
        x0, y0, x1, y1 = p.footprint
        tallest = max([p.item.size[2]] + [m.transform.translation[2] + furniture.find(m.source.furniture).size[2]
                                          for m in small if x0 <= m.transform.translation[0] <= x1
                                          and y0 <= m.transform.translation[1] <= y1])
        x, y, z = p.x, p.y, tallest + float(rng.uniform(0.3, 0.6))
    else:
        x, y, z = W / 2 - 0.4, D / 2 - 0.4, 1.5
    return LightDef(kind="point", power=float(rng.uniform(10, 35)), color=kelvin_rgb(float(rng.uniform(2400, 3200))),
                    translation=(float(x), float(y), float(z)))


FRAMES = ((0.05, 0.05, 0.05), (0.9, 0.9, 0.88), (0.35, 0.22, 0.12), (0.6, 0.5, 0.3))  # black, white, walnut, oak
# Each wall by its inward normal, as (name, yaw of a picture facing into the room).
WALL_YAW = {"north": 0.0, "south": 180.0, "east": -90.0, "west": 90.0}


def _on_wall(wall: str, W: float, D: float, s: float, w: float) -> tuple[float, float, tuple]:
    """A picture ``w`` wide centred ``s`` metres along ``wall`` (from its left end seen from the
    room) -> its centre (x, y) 2 cm off the wall, and the floor strip in front of it (x0, y0, x1,
    y1; 0.6 m deep) where furniture would stand in its way."""
    deep, off = 0.6, 0.02
    if wall == "north":
        x = -W / 2 + s
        return x, D / 2 - off, (x - w / 2, D / 2 - deep, x + w / 2, D / 2)
    if wall == "south":
        x = W / 2 - s
        return x, -D / 2 + off, (x - w / 2, -D / 2, x + w / 2, -D / 2 + deep)
    if wall == "east":
        y = D / 2 - s
        return W / 2 - off, y, (W / 2 - deep, y - w / 2, W / 2, y + w / 2)
    y = -D / 2 + s
    return -W / 2 + off, y, (-W / 2, y - w / 2, -W / 2 + deep, y + w / 2)


def pictures(rng, W: float, D: float, H: float, window, placed: list[Placed], count: tuple[int, int],
             library: list, hung: list | None = None) -> tuple[list[SceneMesh], list[dict]]:
    """Framed photographs on the walls, centred 1.1-1.9 m up: clear of the window, of each other, of
    what already hangs (``hung``: (wall, s0, s1) spans) and of any furniture within 0.6 m of the
    wall that reaches their bottom edge (a try that does not fit is skipped) -> their meshes and
    credits."""
    n = int(rng.integers(count[0], count[1] + 1))
    if not library or n == 0:
        return [], []
    meshes, credits, hung = [], [], list(hung or [])
    for k in range(n):
        pic = library[int(rng.integers(len(library)))]
        h = float(rng.uniform(0.35, 0.7))
        w, border = h * pic.aspect, float(rng.uniform(0.02, 0.06))
        wall = ("north", "south", "east", "west")[int(rng.integers(4))]
        length = W if wall in ("north", "south") else D
        s = float(rng.uniform(0.3 + w / 2, max(0.31 + w / 2, length - 0.3 - w / 2)))
        z = float(rng.uniform(1.1, 1.9))
        frame = FRAMES[int(rng.integers(len(FRAMES)))]
        fits = w + 2 * border <= length - 0.6 and z + h / 2 + border <= H - 0.1
        if not fits or not _free(wall, s, w + 2 * border, z - h / 2 - border, window, W, D, placed, hung):
            continue
        hung.append((wall, s - w / 2 - border, s + w / 2 + border))
        x, y, _ = _on_wall(wall, W, D, s, w)
        rot = (0.0, 0.0, WALL_YAW[wall])
        meshes += [
            SceneMesh(name=f"picture_{k}_frame", source={"box": (w + 2 * border, 0.03, h + 2 * border)},
                      transform=Transform(translation=(x, y, z), rotation=rot), collide=False,
                      material=SceneMaterial(base_color=frame, roughness=0.5)),
            SceneMesh(name=f"picture_{k}", source={"box": (w, 0.031, h)}, collide=False,
                      transform=Transform(translation=(x, y, z), rotation=rot),
                      material=SceneMaterial(texture=str(pic.path), uv_scale=(1.0 / w, 1.0 / h), roughness=0.35,
                                             specular=0.4)),
        ]
        credits.append(pic.credit)
    return meshes, credits


# Each wall by the yaw of a piece standing with its back to it (the front faces into the room).
WALL_OF_YAW = {0: "north", 180: "south", -90: "east", 90: "west"}
INWARD = {"north": (0.0, -1.0), "south": (0.0, 1.0), "east": (-1.0, 0.0), "west": (1.0, 0.0)}


def _along(wall: str, x: float, y: float, W: float, D: float) -> float:
    """Where (x, y) lies along ``wall``, from its left end seen from the room (``_on_wall``'s s)."""
    return {"north": x + W / 2, "south": W / 2 - x, "east": D / 2 - y, "west": y + D / 2}[wall]


def pinboards(rng, W: float, D: float, window, placed: list[Placed], cache: Path):
    """Above every desk or bench against a wall (not under the window): a cork board with pages,
    posters and covers pinned on it, as offices have behind their desks -> (meshes, credits, the
    (wall, s0, s1) spans they take)."""
    meshes, credits, spans = [], [], []
    for k, p in enumerate(placed):
        wall = WALL_OF_YAW.get(int(round(p.yaw)) if not p.middle else None)
        if wall is None or not is_worktop(p.item) or rng.random() < 0.2:
            continue
        w = float(min(p.item.size[0] - 0.1, rng.uniform(0.8, 1.4)))
        h = float(rng.uniform(0.6, 0.9))
        s = _along(wall, p.x, p.y, W, D) + float(rng.uniform(-0.15, 0.15)) * (p.item.size[0] - w)
        x, y, _ = _on_wall(wall, W, D, s, w)
        if wall == "north" and x - w / 2 < window[1] + 0.1 and window[0] - 0.1 < x + w / 2 or w < 0.5:
            continue
        # Low, just over the desk's back row: the part of the wall a camera looking at the desk sees.
        z = float(open_top(p.item)) + float(rng.uniform(0.2, 0.45)) + h / 2
        rot = (0.0, 0.0, WALL_YAW[wall])
        cork = printed.printed(cache, "cardboard", int(rng.integers(printed.VARIANTS["cardboard"])))
        meshes.append(SceneMesh(name=f"pinboard_{k:02d}", source={"box": (w, 0.015, h)}, collide=False,
                                transform=Transform(translation=(x, y, z), rotation=rot),
                                material=SceneMaterial(texture=str(cork.path), uv_scale=(2.0 / w, 2.0 / h),
                                                       base_color=(0.9, 0.75, 0.6), roughness=0.9, specular=0.2)))
        credits += list(cork.credits)
        spans.append((wall, s - w / 2, s + w / 2))
        nx, ny = INWARD[wall]
        for j in range(int(rng.integers(5, 13))):  # pinned sheets, overlapping as they do
            kind = ("page", "poster", "cover", "page")[int(rng.integers(4))]
            sw = float(rng.uniform(0.15, 0.3))
            sh = sw / printed.SIZES[kind][0] * printed.SIZES[kind][1]
            ds, dz = float(rng.uniform(-(w - sw) / 2, (w - sw) / 2)), float(rng.uniform(-(h - sh) / 2, (h - sh) / 2))
            px, py, _ = _on_wall(wall, W, D, s + ds, sw)
            off = 0.01 + 0.0005 * j  # in front of the cork, each sheet over the ones before
            sheet = printed.printed(cache, kind, int(rng.integers(printed.VARIANTS[kind])))
            meshes.append(SceneMesh(name=f"pinboard_{k:02d}_{kind}_{j}", source={"box": (sw, 0.0005, sh)}, collide=False,
                                    transform=Transform(translation=(px + nx * off, py + ny * off, z + dz), rotation=rot),
                                    material=SceneMaterial(texture=str(sheet.path), uv_scale=(1.0 / sw, 1.0 / sh),
                                                           roughness=0.7, specular=0.3)))
            credits += list(sheet.credits)
    return meshes, credits, spans


def _free(wall: str, s: float, w: float, bottom: float, window, W: float, D: float, placed: list[Placed],
          hung) -> bool:
    """No window, picture or piece of furniture reaching ``bottom`` where a picture would hang."""
    if any(h[0] == wall and s - w / 2 - 0.1 < h[2] and h[1] < s + w / 2 + 0.1 for h in hung):
        return False
    _, _, (x0, y0, x1, y1) = _on_wall(wall, W, D, s, w)
    if wall == "north" and x0 < window[1] + 0.15 and window[0] - 0.15 < x1:
        return False
    return not any(p.item.size[2] >= bottom - 0.05 and _overlaps((x0, y0, x1, y1), [p]) for p in placed)


def _room_shape(rng, params: RoomParams):
    W, D, H = (float(rng.uniform(*params.width)), float(rng.uniform(*params.depth)),
               float(rng.uniform(*params.height)))
    win_w = float(rng.uniform(1.0, min(2.0, W - 1.2)))
    wx = float(rng.uniform(-W / 2 + 0.5 + win_w / 2, W / 2 - 0.5 - win_w / 2))
    window = (wx - win_w / 2, wx + win_w / 2, float(rng.uniform(0.8, 1.0)), float(rng.uniform(2.0, min(2.3, H - 0.2))))
    return W, D, H, window


def _relief(rng, cache: Path, kind: str, strength: tuple[float, float]) -> dict:
    """A normal map of the installed CC0 set suiting ``kind``, its strength and a roughness variation,
    as SceneMaterial fields (none when the set is not installed)."""
    maps = pmndrs.normal_maps(cache, kind)
    if not maps:
        return {}
    m = maps[int(rng.integers(len(maps)))]
    return {"normal_map": f"normals:{m.name}", "normal_strength": _step(rng.uniform(*strength)),
            "roughness_variation": _step(rng.uniform(0.08, 0.25))}


def _step(x: float, step: float = 0.05) -> float:
    """``x`` on a grid of ``step``: the maps derived from a material's parameters (scaled normals,
    roughness) are cached by those parameters, and a few hundred grid points are reused from room
    to room where continuous draws would make new maps for every room."""
    return round(round(float(x) / step) * step, 6)


def _tint(rng, spread: float = 0.06, level: tuple[float, float] = (0.85, 1.0)) -> tuple[float, float, float]:
    """A near-neutral colour multiplier: instances of one material are never quite the same."""
    base = float(rng.uniform(*level))
    return tuple(float(np.clip(base * (1.0 + rng.uniform(-spread, spread)), 0.0, 1.0)) for _ in range(3))


def _shell(rng, W: float, D: float, H: float, window, cache: Path, library,
           office: bool = False) -> tuple[list[SceneMesh], list[dict]]:
    """Floor, ceiling and walls (textured, with relief), and a rug in half the rooms. Offices and
    labs (``office``) have a dark carpet as often as not, else a floor of ``OFFICE_FLOORS``, walls
    painted white to pale grey and no rug."""
    felt = next((t for t in library if t.kind == "fabric"), None)
    floor_t = _tex(rng, [t for t in library if t.kind == "floor" and (not office or t.name in OFFICE_FLOORS)], "floor")
    wall_t = _tex(rng, [t for t in library if t.kind == "wall" and (not office or t.name in OFFICE_WALLS)], "wall")
    floor_kind = "tiles" if "tile" in floor_t.name and "wood" not in floor_t.name else "wood"
    if office and felt is not None and rng.random() < 0.5:  # offices: dark carpet tiles as often as not
        floor_t = felt
        floor_mat = SceneMaterial(texture=str(felt.path), uv_scale=1.0 / felt.tile, roughness=0.95, specular=0.2,
                                  base_color=CARPETS[int(rng.integers(len(CARPETS)))],
                                  **_relief(rng, cache, "fabric", (0.3, 0.8)))
    else:
        floor_mat = SceneMaterial(texture=str(floor_t.path), uv_scale=1.0 / floor_t.tile, base_color=_tint(rng),
                                  roughness=_step(rng.uniform(0.4, 0.75)), **_relief(rng, cache, floor_kind, (0.15, 0.5)))
    paints = OFFICE_PAINTS if office else PAINTS
    paint = paints[int(rng.integers(len(paints)))]
    wall_mat = SceneMaterial(texture=str(wall_t.path), base_color=paint, uv_scale=1.0 / wall_t.tile, roughness=0.85,
                             specular=0.3, **_relief(rng, cache, "stone" if "brick" in wall_t.name else "wall", (0.1, 0.4)))
    meshes = [
        SceneMesh(name="floor", source={"plane": (W, D)}, material=floor_mat),
        _box("ceiling", (W + 2 * WALL, D + 2 * WALL, WALL), (0, 0, H + WALL / 2),
             SceneMaterial(base_color=(0.82, 0.82, 0.8), roughness=0.9), collide=False),
        *_walls(W, D, H, window, wall_mat),
    ]
    rug = _rug(rng, W, D, felt)
    if office:  # drawn all the same, so that the furniture after it is drawn as in other kinds of room
        rug = []
    return meshes + rug, list({c["asset"]: c for c in [floor_t.credit, wall_t.credit] + ([felt.credit] if rug else [])}.values())


def _furniture_meshes(rng, placed: list[Placed], cache: Path, library, finish_rng=None,
                      office: bool = False) -> tuple[list[SceneMesh], list[dict]]:
    """The placed pieces, their plain wood and fabric re-dressed (with relief) in most cases; in an
    ``office`` (or lab), in its few woods, and its desks and benches finished as office furniture
    (drawn from ``finish_rng``, a stream of their own, so that the rest of the room is drawn as in
    other kinds)."""
    felt = next((t for t in library if t.kind == "fabric"), None)
    woods = [t for t in library if t.kind == "floor" and "wood" in t.name and (not office or t.name in OFFICE_FLOORS)]
    grain = [t for t in woods if t.name in DESK_GRAIN]
    credit_of = {t.path.as_posix(): t.credit for t in library}
    meshes, credits = [], []
    for k, p in enumerate(placed):
        overrides, _ = redress(rng, p.item, cache, woods, felt)
        if office and finish_rng is not None and grain and is_worktop(p.item):
            overrides |= finish_top(finish_rng, p.item, cache, grain)
        credits += [credit_of[Path(m.texture).as_posix()] for m in overrides.values() if m.texture
                    and Path(m.texture).as_posix() in credit_of]
        meshes.append(SceneMesh(name=f"furniture_{k:02d}", source={"furniture": p.item.id}, materials=overrides,
                                transform=Transform(translation=(p.x, p.y, 0.0), rotation=(0.0, 0.0, p.yaw))))
    return meshes, credits


def top_materials(item: furniture.FurnitureItem, cache: Path) -> list[str]:
    """The names of a desk's or bench's materials that make its top: its woods (by name) and its
    textured materials, not its metal, rubber or glass parts, legs, handles or locks."""
    from ..assets.meshfiles import obj as obj_reader

    names = []
    for name, (mat, lib) in sorted(obj_reader.materials_of(furniture.extract(item, cache)).items()):
        textured = bool(mat.map_kd) and obj_reader.texture_path(lib, mat.map_kd).is_file()
        if (textured or any(w in name.lower() for w in WOOD_WORDS)) and not NOT_TOP_WORDS.search(name):
            names.append(name)
    return names


def finish_top(rng, item: furniture.FurnitureItem, cache: Path, grain: list) -> dict[str, SceneMaterial]:
    """One finish of ``DESK_FINISHES`` for all of a worktop's top materials: a light wood texture
    tinted so that its mean colour is the finish's -> ``materials:`` overrides. A tint is at most
    1, so a finish comes out up to a sixth darker than drawn on a grain texture that is nearly light
    enough for it, and darker still where none is."""
    target = srgb_to_linear(np.array(DESK_FINISHES[int(rng.integers(len(DESK_FINISHES)))]))
    target = target * float(rng.uniform(0.9, 1.05))
    tints = [target / np.maximum(mean_linear_colour(Path(t.path)), 1e-3) for t in grain]
    fits = [k for k, tint in enumerate(tints) if tint.max() <= 1.2] or [int(np.argmin([t.max() for t in tints]))]
    k = fits[int(rng.integers(len(fits)))]
    t, tint = grain[k], tints[k]
    tint = tuple(float(round(c, 3)) for c in tint / max(1.0, float(tint.max())))
    mat = SceneMaterial(texture=str(t.path), uv_scale=1.0, base_color=tint, roughness=_step(rng.uniform(0.35, 0.6)),
                        **_relief(rng, cache, "wood", (0.1, 0.3)))
    return {name: mat for name in top_materials(item, cache)}


def _lights(rng, W: float, D: float, H: float, window, placed, small, params: RoomParams) -> list[LightDef]:
    """Ceiling panels, a bulb, a lamp, and in most rooms the sun through the window: light that
    casts hard shadows next to bright patches, as real rooms have."""
    n = int(rng.integers(1, 4))
    colour = kelvin_rgb(float(rng.uniform(3500, 6500)))
    total = float(rng.uniform(80, 240))
    size = (1.2, 0.3) if rng.random() < 0.6 else (0.6, 0.6)
    spots = [(float((k + 0.5) / n * W - W / 2 + rng.uniform(-0.2, 0.2)), float(rng.uniform(-D / 4, D / 4)))
             for k in range(n)]
    desk = next((p for p in placed if is_worktop(p.item)), None)
    share = [1.0 / n] * n
    if desk is not None:  # offices hang a panel over the desk: its top is the brightest place in the room
        cx, cy = desk.centre
        spots[0] = (cx, cy - (0.3 if not desk.middle else 0.0))
        share = [0.6] + [0.4 / (n - 1)] * (n - 1) if n > 1 else [1.0]
    lights = [LightDef(kind="area", power=total * f, size=size, color=colour, translation=(x, y, H - 0.02))
              for (x, y), f in zip(spots, share)]
    lights += [
        LightDef(kind="point", power=float(rng.uniform(10, 40)), color=kelvin_rgb(float(rng.uniform(2700, 4000))),
                 translation=(float(rng.uniform(-W / 2 + 0.4, W / 2 - 0.4)), float(rng.uniform(-D / 2 + 0.4, D / 2 - 0.4)),
                              float(rng.uniform(1.6, H - 0.4)))),
        _lamp(rng, placed, W, D, small),
    ]
    if rng.random() < params.sun:
        el, az = math.radians(float(rng.uniform(15, 50))), math.radians(float(rng.uniform(-45, 45)))
        d = (math.sin(az) * math.cos(el), -math.cos(az) * math.cos(el), -math.sin(el))  # into the room, down
        at = ((window[0] + window[1]) / 2, D / 2 + 0.5, (window[2] + window[3]) / 2)
        lights.append(LightDef(kind="sun", power=float(rng.uniform(2.5, 7.0)), color=kelvin_rgb(float(rng.uniform(4800, 6200))),
                               translation=at, look_at=(at[0] + d[0], at[1] + d[1], at[2] + d[2])))
    return lights


def _floor_spots(rng, W: float, D: float, placed: list[Placed], n: int) -> list[tuple[float, float]]:
    """Free spots on the floor along the walls, for bins, bags and boxes."""
    spots = []
    for _ in range(20 * n):
        if len(spots) == n:
            break
        wall = int(rng.integers(4))
        t = float(rng.uniform(-0.5, 0.5))
        x, y = [(t * (W - 0.8), D / 2 - 0.3), (t * (W - 0.8), -D / 2 + 0.3), (W / 2 - 0.3, t * (D - 0.8)),
                (-W / 2 + 0.3, t * (D - 0.8))][wall]
        box = (x - 0.3, y - 0.3, x + 0.3, y + 0.3)
        if not _overlaps(box, placed) and all(math.dist((x, y), q) > 0.6 for q in spots):
            spots.append((x, y))
    return spots


def random_room(seed: int, cache: Path, kind: str | None = None,
                params: RoomParams = RoomParams()) -> tuple[SceneFile, list[dict]]:
    """The room of ``seed`` and the credits of every third-party asset in it."""
    rng = np.random.default_rng(seed)
    kind = kind or params.kinds[int(rng.integers(len(params.kinds)))]
    W, D, H, window = _room_shape(rng, params)
    library = textures.available(cache)
    meshes, credits = _shell(rng, W, D, H, window, cache, library, office=kind in OFFICE_KINDS)
    items = _fits(kind_items(kind, params.categories), W, D, H)
    if not items:
        raise furniture.LibraryError(f"no furniture of kind {kind!r} fits a {W:.1f} x {D:.1f} x {H:.1f} m room")
    worktops = [i for i in furniture.catalogue() if re.match(WORKTOPS[kind], i.id)] if kind in WORKTOPS else None
    placed = furnish(rng, items, W, D, window, n_wall=int(rng.integers(params.wall_pieces[0], params.wall_pieces[1] + 1)),
                     n_middle=int(rng.integers(params.middle_pieces[0], params.middle_pieces[1] + 1)), worktops=worktops,
                     island=params.islands)
    pieces, dressed = _furniture_meshes(rng, placed, cache, library, finish_rng=np.random.default_rng((seed, 16)),
                                       office=kind in OFFICE_KINDS)
    meshes += pieces
    credits += [p.item.credit for p in placed] + dressed
    desk_meshes, desk_lights, desk_credits, focus = dress_worktops(rng, placed, cache, params.density, params.boards)
    meshes += desk_meshes
    credits += desk_credits
    small = clutter(rng, placed, furniture.small_items(), params.clutter)
    meshes += small
    credits += [furniture.find(m.source.furniture).credit for m in small]
    spots = _floor_spots(rng, W, D, placed + island_keep_out(placed), 4)
    for k, (item, x, y, yaw) in enumerate(props.floor_items(rng, spots, params.density)):
        meshes.append(SceneMesh(name=f"floor_item_{k:02d}", source={"furniture": item.id},
                                transform=Transform(translation=(x, y, 0.001), rotation=(0.0, 0.0, yaw))))
        credits.append(item.credit)
    lights = _lights(rng, W, D, H, window, placed, small, params) + desk_lights
    world = World(envmap=OUTDOOR_HDRIS[int(rng.integers(len(OUTDOOR_HDRIS)))], strength=float(rng.uniform(0.4, 0.9)),
                  rotation=float(rng.uniform(0, 360)))
    boards, board_credits, spans = pinboards(rng, W, D, window, placed, cache) if params.density > 0 else ([], [], [])
    meshes += boards
    hung, hung_credits = pictures(rng, W, D, H, window, placed, params.pictures, picture_library.available(), spans)
    hung_credits = board_credits + hung_credits
    meshes += hung
    sf = SceneFile(name=f"random_room_{kind}", meshes=meshes, lights=lights, world=world, focus=focus,
                   description=f"random_room seed {seed}, kind {kind}, {len(placed)} pieces of furniture")
    return sf, credits + hung_credits


# Built-in furnished rooms: one fixed room per kind (a seed picked so that the room has ten or more
# pieces of furniture with stages on them), furnished more densely than the random ones. They are
# the paper's fixed artist-made scenes in spirit; random_room draws a new one per arrangement.
FIXED_PARAMS = RoomParams(width=(5.0, 6.0), depth=(4.2, 5.0), height=(2.6, 2.9), wall_pieces=(11, 13),
                          middle_pieces=(2, 2), clutter=(1, 3))
FIXED_ROOMS: dict[str, tuple[str, int]] = {
    "living_room": ("living_room", 101),
    "kitchen": ("kitchen", 202),
    "office": ("office", 303),
    "bedroom": ("bedroom", 404),
    "workshop": ("workshop", 505),
    "shop": ("shop", 606),
    "office_desk": ("office_desk", 707),
    "lab": ("lab", 808),
}


def fixed_room(name: str, cache: Path, density: float = 1.0) -> tuple[SceneFile, list[dict]]:
    kind, seed = FIXED_ROOMS[name]
    sf, credits = random_room(seed, cache, kind=kind, params=replace(FIXED_PARAMS, density=density))
    return sf.model_copy(update={"name": name}), credits

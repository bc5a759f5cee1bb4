"""Write a small user scene the way other tools export them, then build it with specsynth.

    python examples/byo_scene/make_scene.py /tmp/byo        # writes the files below
    specsynth build /tmp/byo/spec.yaml --out /tmp/byo/out    # Cycles; --set 'backend={name: mitsuba}'

Files (all generated here, nothing downloaded):
- ``room.glb``: glTF 2.0 (+Y up, metres) with a floor (checker base-colour texture, rough), two
  walls (plain plaster colour: two nodes sharing one wall mesh, instancing) and a low shelf
  board 10 cm above the floor;
- ``table.obj`` + ``table.mtl`` + ``wood.png``: a table whose top has ``map_Kd`` wood and whose
  legs are a dark metal (``Kd``, ``Pm``, ``Ns``);
- ``scene.yaml``: both meshes, a ceiling light, a grey world, and no stages: specsynth finds them;
- ``scene.glb``: the same room and table as one GLB, to give directly as ``scenes: [{file: scene.glb}]``;
- ``spec.yaml``: six built-in objects dropped onto those stages.
"""

from __future__ import annotations

import argparse
import io
from pathlib import Path

import numpy as np
from PIL import Image

FLOOR = 3.0  # metres, square
TABLE_TOP = 0.72  # metres above the floor
TABLE_SIZE = (1.2, 0.8)
BOARD_AT = (-0.9, 0.115, 0.9)  # glTF (x, y up, z): in our frame x = -0.9, y = -0.9, top at z = 0.13


def checker(n: int = 8, size: int = 256) -> Image.Image:
    cell = size // n
    ij = (np.arange(size) // cell)
    board = (ij[:, None] + ij[None, :]) % 2
    light, dark = np.array([225, 215, 190]), np.array([70, 95, 140])
    return Image.fromarray(np.where(board[..., None] == 1, light, dark).astype(np.uint8))


def wood(size: int = 256) -> Image.Image:
    y, x = np.mgrid[0:size, 0:size] / size
    rings = 0.5 + 0.5 * np.sin(40 * x + 4 * np.sin(6 * y))
    base = np.array([150, 90, 45]) + rings[..., None] * np.array([60, 40, 20])
    return Image.fromarray(np.clip(base, 0, 255).astype(np.uint8))


def room_glb() -> bytes:
    import trimesh
    from trimesh.visual.material import PBRMaterial

    floor = trimesh.Trimesh(  # glTF: +Y up, so the floor lies in the XZ plane
        vertices=[[-FLOOR / 2, 0, FLOOR / 2], [FLOOR / 2, 0, FLOOR / 2], [FLOOR / 2, 0, -FLOOR / 2], [-FLOOR / 2, 0, -FLOOR / 2]],
        faces=[[0, 1, 2], [0, 2, 3]], process=False)
    floor.visual = trimesh.visual.TextureVisuals(
        uv=[[0, 0], [3, 0], [3, 3], [0, 3]],
        material=PBRMaterial(name="floor_checker", baseColorTexture=checker(), roughnessFactor=0.7, metallicFactor=0.0))
    wall = trimesh.creation.box((FLOOR, 1.2, 0.05))
    wall.unmerge_vertices()  # flat shading: a vertex per face corner, as DCC exporters write boxes
    wall.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(name="plaster", baseColorFactor=[0.72, 0.66, 0.55, 1.0], roughnessFactor=0.9, metallicFactor=0.0))
    board = trimesh.creation.box((0.9, 0.03, 0.4))  # a low shelf board: its top is a stage, the floor under it is not
    board.unmerge_vertices()
    board.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(name="board_white", baseColorFactor=[0.85, 0.85, 0.82, 1.0], roughnessFactor=0.4, metallicFactor=0.0))
    scene = trimesh.Scene()
    scene.add_geometry(floor, node_name="floor")
    scene.add_geometry(board, node_name="low_board", transform=trimesh.transformations.translation_matrix(BOARD_AT))
    scene.add_geometry(wall, node_name="wall_back", transform=trimesh.transformations.translation_matrix((0, 0.6, -FLOOR / 2)))
    turn = trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0))
    scene.add_geometry(wall, node_name="wall_side", geom_name="geometry_1",
                       transform=trimesh.transformations.translation_matrix((-FLOOR / 2, 0.6, 0)) @ turn)
    return scene.export(file_type="glb")


def _box(lo, hi) -> tuple[list, list]:
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x, y, z) for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)]
    f = [(0, 2, 3), (0, 3, 1), (4, 5, 7), (4, 7, 6), (0, 1, 5), (0, 5, 4),
         (2, 6, 7), (2, 7, 3), (0, 4, 6), (0, 6, 2), (1, 3, 7), (1, 7, 5)]
    return v, f


def table_obj() -> tuple[str, str]:
    """OBJ in metres, +Z up (OBJ has no fixed up axis; the scene file could rotate it)."""
    sx, sy = TABLE_SIZE[0] / 2, TABLE_SIZE[1] / 2
    lines = ["mtllib table.mtl", "o table"]
    n = 0
    # Top: its own vertices with UVs so the wood texture maps once across it.
    v, f = _box((-sx, -sy, TABLE_TOP - 0.04), (sx, sy, TABLE_TOP))
    lines += [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in v]
    lines += [f"vt {(x + sx) / (2 * sx):.4f} {(y + sy) / (2 * sy):.4f}" for x, y, _ in v]
    lines.append("usemtl wood_top")
    lines += [f"f {a + 1}/{a + 1} {b + 1}/{b + 1} {c + 1}/{c + 1}" for a, b, c in f]
    n += len(v)
    lines.append("usemtl leg_metal")
    for cx in (-sx + 0.05, sx - 0.05):
        for cy in (-sy + 0.05, sy - 0.05):
            v, f = _box((cx - 0.025, cy - 0.025, 0.0), (cx + 0.025, cy + 0.025, TABLE_TOP - 0.04))
            lines += [f"v {x:.4f} {y:.4f} {z:.4f}" for x, y, z in v]
            lines += [f"f {a + n + 1} {b + n + 1} {c + n + 1}" for a, b, c in f]
            n += len(v)
    mtl = "\n".join([
        "newmtl wood_top", "Kd 0.8 0.8 0.8", "Ns 200", "map_Kd wood.png", "",
        "newmtl leg_metal", "Kd 0.05 0.05 0.06", "Pm 1.0", "Pr 0.35", "",
    ])
    return "\n".join(lines) + "\n", mtl


SCENE_YAML = f"""\
# A user scene from files: a glTF room (floor + walls) and an OBJ+MTL table.
version: 1
name: byo_room
meshes:
  - name: room
    source: room.glb            # glTF: +Y up, converted to +Z up; every material kept
  - name: table
    source: table.obj           # OBJ + MTL: wood_top (map_Kd) and leg_metal (Kd, Pm, Pr)
    transform: {{translation: [0.3, 0.2, 0]}}
lights:
  - {{kind: area, power: 120, size: [1.0, 1.0], translation: [0, 0, 2.6]}}
  - {{kind: point, power: 60, translation: [1.2, 1.2, 1.8]}}
world: {{color: [0.15, 0.15, 0.16]}}
# No stages: they are found in the geometry (the table top and the free floor).
"""

SPEC_YAML = """\
version: 1
name: byo_demo
seed: 3
intrinsics: {width: 320, height: 240, fx: 286.0, fy: 286.0, cx: 160.0, cy: 120.0}
objects: {builtin: [duck, mug, lego, jenga]}
scenes: [{file: scene.yaml}]
arrangements: {count: 2}
cameras: {per_arrangement: 2, elevation: [30, 70], distance: [0.6, 1.2]}
quality: {level: low}
backend: {name: cycles, denoise: true}
outputs: {depth_scale: 0.25}
"""


def whole_scene_glb(folder: Path) -> bytes:
    """The same scene as one GLB: the room's nodes plus the OBJ table (turned to glTF's +Y up and
    moved where scene.yaml puts it), every material kept."""
    import trimesh

    scene = trimesh.load(folder / "room.glb", force="scene")
    table = trimesh.load(folder / "table.obj", force="scene", group_material=True)
    z_up_to_y_up = trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))
    place = trimesh.transformations.translation_matrix((0.3, 0.2, 0.0))  # as in scene.yaml, our +Z-up frame
    from trimesh.visual.material import PBRMaterial

    # As table.mtl says: wood_top has the wood texture, leg_metal is a dark rough metal.
    for name, geom in table.geometry.items():
        simple = geom.visual.material
        is_top = getattr(simple, "image", None) is not None
        geom.visual.material = PBRMaterial(
            name="wood_top" if is_top else "leg_metal",
            baseColorTexture=simple.image if is_top else None,
            baseColorFactor=[1.0, 1.0, 1.0, 1.0] if is_top else [0.05, 0.05, 0.06, 1.0],
            metallicFactor=0.0 if is_top else 1.0, roughnessFactor=0.55 if is_top else 0.35)
        scene.add_geometry(geom, node_name=f"table_{name}", transform=z_up_to_y_up @ place)
    return scene.export(file_type="glb")


def write_all(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "room.glb").write_bytes(room_glb())
    obj, mtl = table_obj()
    (folder / "table.obj").write_text(obj)
    (folder / "table.mtl").write_text(mtl)
    buf = io.BytesIO()
    wood().save(buf, format="PNG")
    (folder / "wood.png").write_bytes(buf.getvalue())
    (folder / "scene.glb").write_bytes(whole_scene_glb(folder))
    (folder / "scene.yaml").write_text(SCENE_YAML)
    (folder / "spec.yaml").write_text(SPEC_YAML)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", type=Path)
    write_all(ap.parse_args().folder)


if __name__ == "__main__":
    main()

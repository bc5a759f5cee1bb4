"""Scenes made of the files users have: glTF/GLB and OBJ+MTL with every material kept.

The scene under test is the one ``examples/byo_scene/make_scene.py`` writes: a glTF room (checker
floor, instanced walls) and an OBJ table (``map_Kd`` wood top, metal legs)."""

from __future__ import annotations

import importlib.util
import json
import re
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from test_hostile import png_header

from specsynth.assets import meshfiles
from specsynth.assets.meshio import read_mesh
from specsynth.scenes import SceneError, load_scene, scene_fingerprint
from specsynth.spec.models import SceneRef

ROOT = Path(__file__).resolve().parents[1]


def _example():
    spec = importlib.util.spec_from_file_location("make_scene", ROOT / "examples" / "byo_scene" / "make_scene.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture()
def byo(tmp_path) -> Path:
    folder = tmp_path / "byo"
    _example().write_all(folder)
    return folder


def _load(folder: Path, cache: Path, scene: str = "scene.yaml", clearance: float | None = None):
    return load_scene(SceneRef(file=str(folder / scene)), folder, cache=cache, clearance=clearance)


# --------------------------------------------------------------------------- readers


def test_gltf_parts_are_z_up_with_node_transforms_and_instancing(byo, tmp_path):
    parts = {p.name: p for p in meshfiles.read_parts(byo / "room.glb", tmp_path / "tex")}
    assert set(parts) == {"floor_checker", "plaster", "board_white"}
    floor = parts["floor_checker"].mesh
    assert np.allclose(floor.vertices[:, 2], 0) and np.ptp(floor.vertices[:, 0]) == pytest.approx(3.0)
    assert np.allclose(floor.normals, [0, 0, 1], atol=1e-6)  # +Y up in the file -> +Z up here
    walls = parts["plaster"].mesh.vertices
    assert walls[:, 2].min() == pytest.approx(0.0, abs=1e-6) and walls[:, 2].max() == pytest.approx(1.2, abs=1e-6)
    # Two nodes share one wall mesh: the back wall (glTF z = -1.5 -> our y = +1.5) and the side wall.
    assert walls[:, 1].max() == pytest.approx(1.525, abs=1e-4) and walls[:, 0].min() == pytest.approx(-1.525, abs=1e-4)
    mat = parts["floor_checker"].material
    assert mat.texture and Path(mat.texture).parent == tmp_path / "tex" and mat.roughness == pytest.approx(0.7)
    assert mat.metallic == 0.0 and parts["plaster"].material.base_color == pytest.approx((0.72, 0.66, 0.55), abs=3e-3)


def test_obj_parts_map_mtl_statements(byo):
    parts = {p.name: p for p in meshfiles.read_parts(byo / "table.obj", byo / "unused")}
    top, legs = parts["wood_top"], parts["leg_metal"]
    assert top.material.texture == str(byo / "wood.png") and top.mesh.uv is not None
    assert top.material.roughness == pytest.approx(1 - np.sqrt(200 / 1000))  # Blender's Ns rule
    assert legs.material.metallic == 1.0 and legs.material.roughness == pytest.approx(0.35)  # Pm, Pr
    assert legs.material.base_color == pytest.approx((0.05, 0.05, 0.06)) and legs.mesh.uv is None
    assert meshfiles.source_files(byo / "table.obj") == [byo / "table.obj", byo / "table.mtl", byo / "wood.png"]


def test_obj_missing_texture_warns_and_falls_back_to_kd(byo):
    (byo / "wood.png").unlink()
    with pytest.warns(UserWarning, match=r"material .wood_top.: base colour texture wood.png is missing; using Kd"):
        parts = {p.name: p for p in meshfiles.read_parts(byo / "table.obj", byo / "unused")}
    assert parts["wood_top"].material.texture is None
    assert parts["wood_top"].material.base_color == pytest.approx((0.8, 0.8, 0.8))


def test_gltf_emission_and_defaults(tmp_path):
    import trimesh
    from trimesh.visual.material import PBRMaterial

    box = trimesh.creation.box((0.2, 0.2, 0.2))
    box.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="lamp", emissiveFactor=[1.0, 0.5, 0.25]))
    (tmp_path / "lamp.glb").write_bytes(trimesh.Scene([box]).export(file_type="glb"))
    (part,) = meshfiles.read_parts(tmp_path / "lamp.glb", tmp_path / "tex")
    assert part.material.emission == pytest.approx((1.0, 0.5, 0.25))
    assert part.material.roughness == 1.0 and part.material.metallic == 1.0  # glTF's defaults when absent


@pytest.mark.parametrize("damage, message", [
    (lambda b: b[: len(b) // 2], "truncated GLB"),
    (lambda b: b"PK\x03\x04" + b[4:], "not a GLB file"),
    (lambda b: b[:20] + b"\xff" * 8 + b[28:], "JSON is not valid"),
])
def test_broken_glb_is_a_located_error(byo, tmp_path, damage, message):
    bad = tmp_path / "bad.glb"
    bad.write_bytes(damage((byo / "room.glb").read_bytes()))
    with pytest.raises(meshfiles.MeshFileError, match=message) as e:
        meshfiles.read_parts(bad, tmp_path / "tex")
    assert str(bad) in str(e.value)


def test_required_draco_is_refused_by_name(byo, tmp_path):
    data = (byo / "room.glb").read_bytes()
    n, = struct.unpack_from("<I", data, 12)
    doc = json.loads(data[20 : 20 + n])
    doc["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    rest = data[20 + n :]
    out = struct.pack("<4sII", b"glTF", 2, 20 + len(js) + len(rest)) + struct.pack("<II", len(js), 0x4E4F534A) + js + rest
    (tmp_path / "draco.glb").write_bytes(out)
    with pytest.raises(meshfiles.MeshFileError, match="KHR_draco_mesh_compression.*Draco"):
        meshfiles.read_parts(tmp_path / "draco.glb", tmp_path / "tex")


# --------------------------------------------------------------------------- scenes


def test_scene_keeps_every_material_and_overrides_by_name(byo, tmp_path):
    desc = _load(byo, tmp_path / "cache")
    by_name = {m.name: m for m in desc.meshes}
    assert set(by_name) == {"room/floor_checker", "room/plaster", "room/board_white", "table/wood_top", "table/leg_metal"}
    assert by_name["table/wood_top"].material.texture == str(byo / "wood.png")
    assert read_mesh(by_name["table/wood_top"].mesh_path).vertices[:, 2].max() == pytest.approx(0.72, abs=1e-5)
    assert np.allclose(by_name["table/wood_top"].matrix[:3, 3], [0.3, 0.2, 0])

    text = (byo / "scene.yaml").read_text().replace(
        "    transform: {translation: [0.3, 0.2, 0]}",
        "    transform: {translation: [0.3, 0.2, 0]}\n    materials: {leg_metal: {base_color: [0.9, 0.1, 0.1]}}")
    (byo / "over.yaml").write_text(text)
    over = {m.name: m for m in _load(byo, tmp_path / "cache", "over.yaml").meshes}
    assert over["table/leg_metal"].material.base_color == (0.9, 0.1, 0.1)
    assert over["table/wood_top"].material == by_name["table/wood_top"].material

    (byo / "all.yaml").write_text(text.replace("materials: {leg_metal:", "material: {base_color: [0.2, 0.3, 0.4]}\n    materials: {leg_metal:"))
    every = {m.name: m for m in _load(byo, tmp_path / "cache", "all.yaml").meshes}
    assert every["table/wood_top"].material.base_color == (0.2, 0.3, 0.4)  # `material:` overrides all parts
    assert every["table/leg_metal"].material.base_color == (0.9, 0.1, 0.1)  # ... but a named one wins

    (byo / "typo.yaml").write_text(text.replace("leg_metal: {", "leg_metl: {"))
    with pytest.raises(SceneError, match=r"meshes.table.materials: 'leg_metl' not in table.obj \(it has: leg_metal, wood_top\)"):
        _load(byo, tmp_path / "cache", "typo.yaml")


def test_cached_parts_never_point_at_another_folders_texture(byo, tmp_path):
    cache = tmp_path / "cache"
    _load(byo, cache)
    copy = tmp_path / "copy"
    _example().write_all(copy)  # same bytes, another folder
    desc = _load(copy, cache)
    top = next(m for m in desc.meshes if m.name == "table/wood_top")
    assert top.material.texture == str(copy / "wood.png")


def test_editing_one_texture_changes_the_scene_key(byo):
    before = scene_fingerprint(SceneRef(file=str(byo / "scene.yaml")), byo)
    from PIL import Image

    Image.new("RGB", (8, 8), (10, 200, 10)).save(byo / "wood.png")
    after = scene_fingerprint(SceneRef(file=str(byo / "scene.yaml")), byo)
    assert before != after


@pytest.mark.parametrize("change, says", [
    ("materials: {leg_metl: {base_color: [0.9, 0.1, 0.1]}}", r"meshes.table.materials: 'leg_metl' not in table.obj "
                                                             r"\(it has: leg_metal, wood_top\)"),
    ("material: {texture: notes.png}", r"meshes.table: material: texture .*notes.png is unreadable"),
    ("material: {texture: huge.png}", r"huge.png: over the 67,108,864-pixel limit"),
])
def test_validate_reads_a_scene_files_material_names_and_textures_without_loading_it(byo, change, says):
    """What loading the scene would refuse, found by the scene's key (``validate``) before any
    geometry is read: a misspelt material name, a text file or an image too large as a texture."""
    (byo / "notes.png").write_text("SECRET_TOKEN, not an image")
    png_header(byo / "huge.png", 60000, 60000)
    text = (byo / "scene.yaml").read_text().replace("    transform: {translation: [0.3, 0.2, 0]}",
                                                    f"    transform: {{translation: [0.3, 0.2, 0]}}\n    {change}")
    (byo / "bad.yaml").write_text(text)
    with pytest.raises(SceneError, match=says) as e:
        scene_fingerprint(SceneRef(file=str(byo / "bad.yaml")), byo)
    assert "SECRET_TOKEN" not in str(e.value)


@pytest.mark.parametrize("change", [
    "    transform: {translation: [0.3, 0.2, 0], scale: 1e300}",
    "    transform: {translation: [0.3, 0.2, 0], scale: [1, 1, 1e-9]}",
])
def test_a_scale_no_furniture_has_is_refused(byo, change):
    (byo / "bad.yaml").write_text((byo / "scene.yaml").read_text().replace("    transform: {translation: [0.3, 0.2, 0]}", change))
    with pytest.raises(SceneError, match=re.escape("scale must be within 1e-06..1e+06")):
        scene_fingerprint(SceneRef(file=str(byo / "bad.yaml")), byo)


def test_a_light_past_any_lamps_power_is_refused():
    from pydantic import ValidationError

    from specsynth.scenes.models import LightDef

    assert LightDef(kind="point", power=2000.0).power == 2000.0
    with pytest.raises(ValidationError, match="less than or equal to 10000000"):
        LightDef(kind="point", power=1e308)


def test_a_missing_gltf_buffer_is_named(tmp_path):
    (tmp_path / "room.gltf").write_text(json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": "room.bin", "byteLength": 12}]}))
    with pytest.raises(meshfiles.MeshFileError, match="references 'room.bin', which is missing"):
        meshfiles.source_files(tmp_path / "room.gltf")


# --------------------------------------------------------------------------- automatic stages


def _box_tris(lo, hi) -> np.ndarray:
    import trimesh

    b = trimesh.creation.box(bounds=[lo, hi])
    return np.asarray(b.vertices)[b.faces]


def test_found_stages_are_real_free_upward_surfaces():
    from specsynth.scenes.autostage import AutoStageParams, find_stages

    floor = _box_tris((-2, -2, -0.05), (2, 2, 0.0))
    table = _box_tris((0.5, 0.5, 0.70), (1.5, 1.3, 0.74))
    legs = np.concatenate([_box_tris((x, y, 0.0), (x + 0.05, y + 0.05, 0.70)) for x in (0.5, 1.45) for y in (0.5, 1.25)])
    board = _box_tris((-1.8, -1.8, 0.10), (-0.6, -1.4, 0.12))  # a shelf board 10 cm above the floor
    stages = find_stages(np.concatenate([floor, table, legs, board]), AutoStageParams(clearance=0.6))
    heights = sorted({s.height for s in stages})
    assert heights == pytest.approx([0.0, 0.12, 0.74], abs=0.006)
    top = [s for s in stages if abs(s.height - 0.74) < 0.01]
    assert len(top) == 1 and top[0].area == pytest.approx((1.0 - 0.06) * (0.8 - 0.06), rel=0.08)
    floor_stages = [s for s in stages if s.height < 0.01]
    for s in floor_stages:
        # Never under the board, nor under the table top (0.70 m < clearance from the floor? no: 0.6),
        # and never where a leg stands.
        under_board = s.contains(np.array([[-1.2, -1.6]]))[0]
        assert not under_board
        assert not s.contains(np.array([[0.52, 0.52]]))[0]
    names = [s.name for s in stages]
    assert len(set(names)) == len(names) and "auto_0740mm_1" in names
    assert [s.name for s in find_stages(np.concatenate([floor, table, legs, board]), AutoStageParams(clearance=0.6))] == names


def test_a_low_clearance_allows_the_floor_under_the_table_and_a_high_one_forbids_it():
    from specsynth.scenes.autostage import AutoStageParams, find_stages

    scene = np.concatenate([_box_tris((-2, -2, -0.05), (2, 2, 0.0)), _box_tris((-0.5, -0.5, 0.70), (0.5, 0.5, 0.74))])
    under = np.array([[0.0, 0.0]])
    low = [s for s in find_stages(scene, AutoStageParams(clearance=0.5)) if s.height < 0.01]
    high = [s for s in find_stages(scene, AutoStageParams(clearance=0.9)) if s.height < 0.01]
    assert any(s.contains(under)[0] for s in low)
    assert not any(s.contains(under)[0] for s in high)


def _mesh_instance(tris: np.ndarray, path: Path, name: str):
    from specsynth.assets.meshio import MeshData, write_mesh
    from specsynth.model.ir import MeshInstance, as_tuple

    write_mesh(path, MeshData(vertices=tris.reshape(-1, 3).astype(np.float32),
                              faces=np.arange(len(tris) * 3, dtype=np.int32).reshape(-1, 3)))
    return MeshInstance(name=name, mesh_path=str(path), mesh_key=name, pose=as_tuple(np.eye(4)))


def test_focus_windows_search_only_there_and_fall_back_to_the_whole_scene(tmp_path):
    """With focus windows the search keeps to them (a stage on the table, none on the floor); when
    no stage fits in any window, the whole scene is searched (the floor's stages) rather than none."""
    from specsynth.scenes import _auto_stages

    floor = _mesh_instance(_box_tris((-2, -2, -0.05), (2, 2, 0.0)), tmp_path / "floor.ply", "floor")
    legs = [_box_tris((x, y, 0.0), (x + 0.05, y + 0.05, 0.72)) for x in (0.5, 1.25) for y in (0.5, 1.05)]
    table = _mesh_instance(np.concatenate([_box_tris((0.5, 0.5, 0.72), (1.3, 1.1, 0.75)), *legs]),
                           tmp_path / "table.ply", "table")
    meshes, solid = [floor, table], ["floor", "table"]
    on_table = _auto_stages(tmp_path, meshes, solid, 0.8, [(0.55, 0.55, 1.25, 1.05)])
    assert on_table and all(abs(s.height - 0.75) < 1e-6 for s in on_table.values())
    for s in on_table.values():
        assert all(0.55 - 1e-9 <= x <= 1.25 + 1e-9 and 0.55 - 1e-9 <= y <= 1.05 + 1e-9 for x, y in s.polygon)
    tiny = _auto_stages(tmp_path, meshes, solid, 0.8, [(0.6, 0.6, 0.7, 0.7)])
    assert tiny == _auto_stages(tmp_path, meshes, solid, 0.8)
    assert any(abs(s.height) < 1e-6 for s in tiny.values())


@pytest.mark.parametrize("seed", range(40))
def test_largest_rectangle_matches_brute_force(seed):
    from specsynth.scenes.autostage import largest_rectangle

    rng = np.random.default_rng(seed)
    m = rng.random((int(rng.integers(1, 9)), int(rng.integers(1, 9)))) < rng.uniform(0.3, 0.95)
    best = 0
    for r0 in range(m.shape[0]):
        for r1 in range(r0, m.shape[0]):
            for c0 in range(m.shape[1]):
                for c1 in range(c0, m.shape[1]):
                    if m[r0 : r1 + 1, c0 : c1 + 1].all():
                        best = max(best, (r1 - r0 + 1) * (c1 - c0 + 1))
    area, a, b, c, d = largest_rectangle(m)
    assert area == best
    if area:
        assert m[a : c + 1, b : d + 1].all() and (c - a + 1) * (d - b + 1) == area


@settings(max_examples=150, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), side=st.integers(1, 4))
def test_largest_fitting_rectangle_is_the_best_with_both_sides_long_enough(seed, side):
    """A stage is the rectangle of free cells at least ``side`` cells on both sides whose m x m
    squares' corners cover the most (brute force over every rectangle), and it exists exactly when
    one with both sides long enough does: a long thin strip never hides a stage-sized patch."""
    from specsynth.scenes.autostage import largest_fitting

    rng = np.random.default_rng(seed)
    m = rng.random((int(rng.integers(1, 10)), int(rng.integers(1, 10)))) < rng.uniform(0.4, 0.97)
    best = 0
    for r0, c0 in np.ndindex(m.shape):
        for r1 in range(r0 + side - 1, m.shape[0]):
            for c1 in range(c0 + side - 1, m.shape[1]):
                if m[r0 : r1 + 1, c0 : c1 + 1].all():
                    best = max(best, (r1 - r0 + 2 - side) * (c1 - c0 + 2 - side))
    area, a, b, c, d = largest_fitting(m, side)
    assert (area > 0) == (best > 0)
    if area:
        assert m[a : c + 1, b : d + 1].all() and min(c - a + 1, d - b + 1) >= side
        assert (c - a + 2 - side) * (d - b + 2 - side) == best and area == (c - a + 1) * (d - b + 1)


def test_a_stage_is_found_beside_a_long_thin_strip():
    """A free L at 2 cm cells: a 48 x 6 cell strip (the largest rectangle, 12 cm: too thin to be a
    stage) and a 12 x 16 patch at its end: the patch is the stage."""
    from specsynth.scenes.autostage import AutoStageParams, _rectangles

    free = np.zeros((20, 50), bool)
    free[0:6, 1:49] = True
    free[6:16, 1:13] = True
    stages = _rectangles(free, np.zeros(free.shape), np.zeros(3), 0.02, AutoStageParams())
    assert stages and all(min(np.ptp(np.array(s.polygon), axis=0)) >= 0.2 - 1e-9 for s in stages)


def _panel(yaw: float, x: float, z0: float, z1: float, width: float = 1.2) -> np.ndarray:
    """An open vertical quad (two triangles, no top or bottom face) across the floor at x."""
    c, s_ = np.cos(yaw), np.sin(yaw)
    ends = [np.array([x, 0.0]) + t * np.array([c, s_]) for t in (-width / 2, width / 2)]
    q = [np.array([*ends[0], z0]), np.array([*ends[1], z0]), np.array([*ends[1], z1]), np.array([*ends[0], z1])]
    return np.array([[q[0], q[1], q[2]], [q[0], q[2], q[3]]])


@settings(max_examples=50, deadline=None)
@given(yaw=st.floats(0.0, np.pi), reach=st.floats(0.005, 0.3))
def test_a_vertical_panel_blocks_the_floor_under_it_even_where_it_barely_reaches_the_slab(yaw, reach):
    """Vertical triangles are spans, not points: a bare panel whose lower edge hangs ``reach``
    into the clearance above the floor blocks every floor cell it crosses, whatever its yaw."""
    from specsynth.scenes.autostage import AutoStageParams, find_stages

    params = AutoStageParams(clearance=0.6)
    floor = _box_tris((-2, -2, -0.05), (2, 2, 0.0))
    blocking = _panel(yaw, 0.0, params.clearance - reach, 2.0)
    under = np.array([[t * np.cos(yaw), t * np.sin(yaw)] for t in np.linspace(-0.55, 0.55, 23)])
    for stage in find_stages(np.concatenate([floor, blocking]), params):
        assert not stage.contains(under).any(), stage
    above = _panel(yaw, 0.0, params.clearance + params.height_tol + 0.02, 2.0)  # clear of the slab: no effect
    assert find_stages(np.concatenate([floor, above]), params) == find_stages(floor, params)


@settings(max_examples=50, deadline=None)
@given(yaw=st.floats(0.0, 2 * np.pi), pts=st.lists(st.tuples(st.floats(-1, 1), st.floats(0, 2)), min_size=3, max_size=3))
def test_vertical_spans_lie_on_their_triangle_and_cover_its_height(yaw, pts):
    from specsynth.scenes.autostage import vertical_spans

    (t0, z0), (t1, z1), (t2, z2) = pts
    area2 = abs((t1 - t0) * (z2 - z0) - (t2 - t0) * (z1 - z0))
    if area2 < 1e-3:
        return
    d = np.array([np.cos(yaw), np.sin(yaw)])
    tri = np.array([[*(t * d), z] for t, z in pts])
    xy, lo, hi = vertical_spans(tri[None], 0.01)
    ts = xy @ d
    assert np.all(np.diff(np.sort(ts)) <= 0.01 + 1e-9) and np.all(lo <= hi + 1e-12)
    assert ts.min() - min(t0, t1, t2) <= 0.005 + 1e-9 and max(t0, t1, t2) - ts.max() <= 0.005 + 1e-9
    # Each span is the triangle's cross-section at its t: the lowest and highest points of a fine
    # column of heights that fall inside the triangle (a barycentric test, independent of the code).
    P = np.array(pts)
    zs = np.linspace(-0.01, 2.01, 20201)
    for k in range(0, len(ts), max(1, len(ts) // 12)):
        q = np.stack([np.full_like(zs, ts[k]), zs], axis=1) - P[0]
        m = np.array([P[1] - P[0], P[2] - P[0]]).T
        u, v = np.linalg.solve(m, q.T)
        inside = (u >= -1e-9) & (v >= -1e-9) & (u + v <= 1 + 1e-9)
        if inside.any():
            assert abs(lo[k] - zs[inside].min()) <= 2e-4 and abs(hi[k] - zs[inside].max()) <= 2e-4
        else:  # a sliver thinner than the column's step
            assert hi[k] - lo[k] <= 2e-4


def test_scene_without_stages_finds_them_and_show_draws_them(byo, tmp_path, capsys):
    from specsynth.cli import main

    desc = _load(byo, tmp_path / "cache", clearance=0.7)  # more than the 0.68 m under the table top
    heights = sorted({round(s.height, 3) for s in desc.stages.values()})
    assert heights == [0.0, 0.13, 0.72]  # the floor, the low board's top and the table top
    under_board = np.array([[x, y] for x in (-1.3, -0.9, -0.5) for y in (-1.05, -0.9, -0.75)])
    for stage in desc.stages.values():  # never on the floor under the board, nor under the table
        if stage.height < 0.01:
            assert not stage.contains(under_board).any() and not stage.contains(np.array([[0.3, 0.2]]))[0], stage
    rc = main(["scenes", "show", str(byo / "scene.yaml"), "--out", str(tmp_path / "top.png"), "--clearance", "0.7"])
    assert rc == 0 and "auto_0720mm_1" in capsys.readouterr().out
    from PIL import Image

    img = np.asarray(Image.open(tmp_path / "top.png").convert("RGB")).astype(int)
    assert img.shape[0] > 300 and ((img[..., 0] > 180) & (img[..., 1] < 120)).sum() > 100  # outlines drawn


def test_no_usable_stage_is_a_located_error(tmp_path):
    (tmp_path / "wall.yaml").write_text("version: 1\nname: w\nmeshes:\n  - {name: wall, source: {box: [0.1, 2, 2]}}\n")
    with pytest.raises(SceneError, match=r"wall.yaml: stages: none found automatically"):
        _load(tmp_path, tmp_path / "cache", "wall.yaml")


# --------------------------------------------------------------------------- a glTF file as the scene


def _with_json(glb: bytes, edit) -> bytes:
    n, = struct.unpack_from("<I", glb, 12)
    doc = json.loads(glb[20 : 20 + n])
    edit(doc)
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    rest = glb[20 + n :]
    return struct.pack("<4sII", b"glTF", 2, 20 + len(js) + len(rest)) + struct.pack("<II", len(js), 0x4E4F534A) + js + rest


def test_gltf_scene_imports_punctual_lights_with_photometric_units(byo, tmp_path):
    import math

    def add_lights(doc):
        doc.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
        doc.setdefault("extensions", {})["KHR_lights_punctual"] = {"lights": [
            {"type": "point", "intensity": 100.0, "color": [1, 0.9, 0.8]},
            {"type": "spot", "intensity": 50.0, "spot": {"innerConeAngle": 0.2, "outerConeAngle": 0.4}},
            {"type": "directional", "intensity": 3000.0},
        ]}
        base = len(doc["nodes"])
        doc["nodes"] += [
            {"translation": [0, 2.5, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}},
            {"translation": [1, 2, 1], "rotation": [-0.7071068, 0, 0, 0.7071068],  # -90 deg about X: points down
             "extensions": {"KHR_lights_punctual": {"light": 1}}},
            {"extensions": {"KHR_lights_punctual": {"light": 2}}},
        ]
        doc["scenes"][doc.get("scene", 0)]["nodes"] += [base, base + 1, base + 2]

    (tmp_path / "lit.glb").write_bytes(_with_json((byo / "room.glb").read_bytes(), add_lights))
    desc = load_scene(SceneRef(file=str(tmp_path / "lit.glb")), tmp_path, cache=tmp_path / "cache")
    point, spot, sun = desc.lights
    assert point.kind == "point" and point.power == pytest.approx(100 * 4 * math.pi / 683)
    assert point.matrix[:3, 3] == pytest.approx([0, 0, 2.5])  # glTF y up -> our z up
    assert point.color == pytest.approx((1, 0.9, 0.8))
    assert spot.spot_angle == pytest.approx(math.degrees(0.8)) and spot.spot_blend == pytest.approx(0.5)
    assert spot.matrix[:3, 3] == pytest.approx([1, -1, 2])
    assert spot.matrix[:3, 2] == pytest.approx([0, 0, 1], abs=1e-6)  # local +Z up: it emits along -Z, down
    assert sun.kind == "sun" and sun.power == pytest.approx(3000 / 683)
    assert desc.world.kind == "color"  # lights given: no default HDRI
    assert {round(s.height, 3) for s in desc.stages.values()} == {0.0, 0.13}  # floor and the low board


def test_gltf_scene_without_lights_gets_the_default_hdri(byo, tmp_path):
    pytest.importorskip("bpy")  # the built-in HDRIs ship with bpy
    desc = load_scene(SceneRef(file=str(byo / "room.glb")), byo, cache=tmp_path / "cache")
    assert desc.world.kind == "envmap" and desc.world.envmap.endswith("interior.exr") and not desc.lights


def test_scene_parse_errors_never_echo_the_file(tmp_path):
    secret = "root:x:0:0:supersecret:/root:/bin/bash"
    (tmp_path / "bad.yaml").write_text(f"name: [unclosed\n{secret}\n")
    with pytest.raises(SceneError) as e:
        _load(tmp_path, tmp_path / "cache", "bad.yaml")
    assert "supersecret" not in str(e.value) and "bad.yaml:" in str(e.value)
    (tmp_path / "bin.yaml").write_bytes(b"\x89PNG\x00\xff\xfe" + secret.encode())
    with pytest.raises(SceneError, match="not a text file") as e:
        _load(tmp_path, tmp_path / "cache", "bin.yaml")
    assert "supersecret" not in str(e.value)


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["cycles", "mitsuba"])
def test_a_glb_given_directly_as_the_scene_builds(byo, tmp_path, backend):
    """The example's room and table as one GLB (scene.glb): builds with found stages, lit by the
    default HDRI, and both textures show."""
    from PIL import Image

    from specsynth.cli import main

    spec = (byo / "spec.yaml").read_text().replace("scenes: [{file: scene.yaml}]", "scenes: [{file: scene.glb}]")
    (byo / "spec_glb.yaml").write_text(spec)
    opts = "{name: cycles, samples: 4, denoise: true}" if backend == "cycles" else "{name: mitsuba, samples: 4}"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["build", str(byo / "spec_glb.yaml"), "--out", str(tmp_path / "out"), "--quiet",
                   "--set", f"backend={opts}", "--set", "arrangements.count=1", "--set", "cameras.per_arrangement=2"])
    assert rc == 0
    gt = json.loads((tmp_path / "out/bop/train_pbr/000000/scene_gt_info.json").read_text())
    # Every accepted view sees its focused object at least 30 % (the visibility pre-check).
    assert len(gt) == 2 and all(max(g["visib_fract"] for g in im) >= 0.3 for im in gt.values())
    desc = load_scene(SceneRef(file=str(byo / "scene.glb")), byo, cache=tmp_path / "c", clearance=0.7)
    assert {round(s.height, 2) for s in desc.stages.values()} == {0.0, 0.13, 0.72}  # floor, board, table top
    pixels = np.concatenate([np.asarray(Image.open(p).convert("RGB")).reshape(-1, 3)
                             for p in sorted((tmp_path / "out/bop/train_pbr/000000/rgb").iterdir())]).astype(int)
    r, g, b = pixels.T
    assert ((b > r + 30) & (b > g + 10)).mean() > 0.01  # the checker's blue tiles
    assert {p.material.texture is not None for p in meshfiles.read_parts(byo / "scene.glb", tmp_path / "t")
            if p.material_name == "wood_top"} == {True}


def test_a_gigantic_mesh_is_refused_before_rendering(tmp_path, monkeypatch):
    from specsynth.assets import meshfiles

    monkeypatch.setattr(meshfiles, "MAX_TRIANGLES", 10)  # the same check, at a size a test can afford
    import trimesh

    trimesh.creation.icosphere(subdivisions=2).export(tmp_path / "ball.stl")
    (tmp_path / "big.yaml").write_text("version: 1\nname: big\nmeshes:\n  - {name: ball, source: ball.stl}\n")
    with pytest.raises(SceneError, match=r"big.yaml: meshes.ball: 320 triangles, over the 10 limit"):
        _load(tmp_path, tmp_path / "cache", "big.yaml")


# --------------------------------------------------------------------------- content keys, end to end


def test_editing_one_texture_reruns_exactly_the_arrangements_in_that_scene(byo, tmp_path):
    """Two scenes in one spec: a new wood texture re-runs the arrangements drawn in the user scene
    (and their views and renders), and none drawn in the built-in room."""
    from PIL import Image

    from specsynth.plan.compiler import compile_spec
    from specsynth.plan.seeds import scene_draw
    from specsynth.run.build import build, plan
    from specsynth.spec.yamlio import load_spec

    spec = byo / "two.yaml"
    spec.write_text((byo / "spec.yaml").read_text()
                    .replace("scenes: [{file: scene.yaml}]", "scenes: [{file: scene.yaml}, {name: room}]")
                    .replace("arrangements: {count: 2}", "arrangements: {count: 6}")
                    .replace("backend: {name: cycles, denoise: true}", "backend: {name: photo}"))
    graph = compile_spec(load_spec(spec))
    in_byo = [a for a in range(6) if scene_draw(graph.spec.seed, f"arr={a:06d}", [1, 1])[0] == 0]
    assert 0 < len(in_byo) < 6
    out = tmp_path / "out"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        build(graph, out, jobs=1)
    done = json.loads((out / ".specsynth" / "manifest.json").read_text())["jobs"]
    import pyarrow.parquet as pq

    scenes = dict(zip(*pq.read_table(out / "parquet" / "images.parquet", columns=["arr", "scene"]).to_pydict().values()))
    assert {a for a, s in scenes.items() if s == "file:scene.yaml"} == {a for a in in_byo if a in scenes}

    Image.new("RGB", (16, 16), (20, 160, 20)).save(byo / "wood.png")
    again = compile_spec(load_spec(spec))
    changed = [a for a in range(6) if again.arrange_job(a).key != graph.arrange_job(a).key]
    assert changed == in_byo
    p = plan(again, out)["stages"]
    assert p["arrange"]["to_run"] == len(in_byo) and p["arrange"]["cached"] == 6 - len(in_byo)
    assert p["render"]["cached"] == sum(1 for k in done["render"] if int(k[4:10]) not in in_byo) > 0


def test_obj_whose_named_mtl_was_renamed_reads_its_own_stem(tmp_path):
    """Sweet Home 3D ships kids_shelves.obj naming kids_shelves_sh3d.mtl beside kids_shelves.mtl."""
    (tmp_path / "shelf.obj").write_text("mtllib shelf_sh3d.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nusemtl red\nf 1 2 3\n")
    (tmp_path / "shelf.mtl").write_text("newmtl red\nKd 0.8 0.1 0.1\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "material library is missing" warning
        (part,) = meshfiles.read_parts(tmp_path / "shelf.obj", tmp_path / "tex")
    assert part.material.base_color == pytest.approx((0.8, 0.1, 0.1))
    assert tmp_path / "shelf.mtl" in meshfiles.source_files(tmp_path / "shelf.obj")


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=400), st.sampled_from([0.0, 0.002, 0.004, 0.01]), st.integers(1, 8),
       st.sampled_from([0.0, 1e-17, 1e-3]))
def test_height_levels_cut_groups_as_the_rule_says(steps, tol, min_count, jitter):
    """One binary search per group gives exactly the rule's groups: sorted heights cut where a
    sample is more than ``tol`` above its group's first (heights on a tol grid test the boundary)."""
    from specsynth.scenes.autostage import height_levels

    z = np.asarray(steps, np.float64) * 0.004 + jitter * (np.arange(len(steps)) % 3)
    zs, want, start = np.sort(z), [], 0
    for i in range(1, len(zs) + 1):  # the rule, one sample at a time
        if i == len(zs) or zs[i] - zs[start] > tol:
            if i - start >= min_count:
                want.append(float(zs[start]))
            start = i
    assert height_levels(z, tol, min_count) == want


@settings(max_examples=200, deadline=None)
@given(st.integers(3, 30), st.integers(3, 30), st.floats(0, 180), st.integers(0, 2**32 - 1))
def test_pinholes_are_filled_and_edges_stay(rows, cols, angle, seed):
    """A rasterised rotated rectangle (a board at any yaw) with cells knocked out inside: filling
    gives back every knocked-out cell that keeps support on its four sides and never grows the
    shape past its edges."""
    from specsynth.scenes.autostage import fill_pinholes

    r, c = np.mgrid[0:40, 0:40] - 19.5
    a = np.radians(angle)
    u, v = r * np.cos(a) + c * np.sin(a), -r * np.sin(a) + c * np.cos(a)
    shape = (np.abs(u) <= rows / 2) & (np.abs(v) <= cols / 2)
    assert np.array_equal(fill_pinholes(shape), shape)  # no edge moves, straight or stepped
    holes = shape.copy()
    inner = np.argwhere(shape & np.roll(shape, 1, 0) & np.roll(shape, -1, 0) & np.roll(shape, 1, 1) & np.roll(shape, -1, 1))
    rng = np.random.default_rng(seed)
    if len(inner):
        picked = inner[rng.choice(len(inner), size=min(3, len(inner)), replace=False)]
        isolated = [p for p in picked if sum(abs(p - q).sum() == 1 for q in picked) == 0]
        for p in isolated:
            holes[tuple(p)] = False
        assert fill_pinholes(holes)[tuple(np.array(isolated).T)].all() if isolated else True


def test_a_cell_without_samples_inside_a_surface_does_not_cut_its_stage(monkeypatch):
    """Samples fall about four to a grid cell, unevenly: a cell of a desk top or a marker board could
    get none, and the margin's erosion made it a 5 x 5 hole that left no stage on a 0.5 x 0.3 m
    board (a dressed desk's objects then went to the floor)."""
    from specsynth.scenes import autostage

    board = np.array([[[-0.25, -0.15, 0.75], [0.25, -0.15, 0.75], [0.25, 0.15, 0.75]],
                      [[-0.25, -0.15, 0.75], [0.25, 0.15, 0.75], [-0.25, 0.15, 0.75]]])
    real = autostage.sample_triangles

    def with_a_pinhole(tris, spacing):
        pts, normals = real(tris, spacing)
        keep = ~((np.abs(pts[:, 0] - 0.02) < 0.0101) & (np.abs(pts[:, 1] - 0.02) < 0.0101))  # the cell at 0.01-0.03 m
        return pts[keep], normals[keep]

    monkeypatch.setattr(autostage, "sample_triangles", with_a_pinhole)
    params = autostage.AutoStageParams(clearance=0.3)
    (stage,) = autostage.find_stages(board, params, (-0.3, -0.2, 0.3, 0.2))
    xs, ys = [p[0] for p in stage.polygon], [p[1] for p in stage.polygon]
    assert max(xs) - min(xs) >= 0.4 and max(ys) - min(ys) >= 0.2

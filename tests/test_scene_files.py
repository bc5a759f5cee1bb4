"""Scenes made of the files users have: glTF/GLB and OBJ+MTL with every material kept.

The scene under test is the one ``examples/byo_scene/make_scene.py`` writes: a glTF room (checker
floor, instanced walls) and an OBJ table (``map_Kd`` wood top, metal legs)."""

from __future__ import annotations

import importlib.util
import json
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest

from specsynth import meshfiles
from specsynth.meshio import read_mesh
from specsynth.scenes import SceneError, load_scene, scene_fingerprint
from specsynth.spec import SceneRef

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


def _load(folder: Path, cache: Path, scene: str = "scene.yaml"):
    return load_scene(SceneRef(file=str(folder / scene)), folder, cache=cache)


# --------------------------------------------------------------------------- readers


def test_gltf_parts_are_z_up_with_node_transforms_and_instancing(byo, tmp_path):
    parts = {p.name: p for p in meshfiles.read_parts(byo / "room.glb", tmp_path / "tex")}
    assert set(parts) == {"floor_checker", "plaster"}
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
    with pytest.warns(UserWarning, match=r"material 'wood_top': texture wood.png is missing; using Kd"):
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
    assert set(by_name) == {"room/floor_checker", "room/plaster", "table/wood_top", "table/leg_metal"}
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


def test_a_missing_gltf_buffer_is_named(tmp_path):
    (tmp_path / "room.gltf").write_text(json.dumps({
        "asset": {"version": "2.0"}, "buffers": [{"uri": "room.bin", "byteLength": 12}]}))
    with pytest.raises(meshfiles.MeshFileError, match="references 'room.bin', which is missing"):
        meshfiles.source_files(tmp_path / "room.gltf")


# --------------------------------------------------------------------------- renders


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["cycles", "mitsuba"])
def test_both_textures_show_in_a_real_render(byo, tmp_path, backend):
    """Cycles and Mitsuba draw the glTF checker floor and the OBJ's wood top in their colours."""
    from specsynth.cli import main
    from PIL import Image

    opts = "{name: cycles, samples: 16, denoise: true}" if backend == "cycles" else "{name: mitsuba, samples: 16}"
    out = tmp_path / backend
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["build", str(byo / "spec.yaml"), "--out", str(out), "--quiet", "--set", f"backend={opts}",
                   "--set", "arrangements.count=1", "--set", "cameras.per_arrangement=2"])
    assert rc == 0
    pixels = np.concatenate([np.asarray(Image.open(p).convert("RGB")).reshape(-1, 3)
                             for p in sorted((out / "bop/train_pbr/000000/rgb").iterdir())]).astype(int)
    r, g, b = pixels.T
    blue_tiles = (b > r + 30) & (b > g + 10)  # the checker's dark tiles (70, 95, 140)
    wood = (r > b + 60) & (r > g + 20)  # the table top (150-210, 90-130, 45-65)
    assert blue_tiles.mean() > 0.02 and wood.mean() > 0.02, (blue_tiles.mean(), wood.mean())

"""Built-in scenes load, stages sit on real geometry, scene files validate with useful errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from specsynth import scenes
from specsynth.assets.meshfiles import primitives as procedural
from specsynth.assets.meshio import read_mesh
from specsynth.scenes import SceneError
from specsynth.spec.models import SceneRef


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("cache")


def _world_mesh(desc):
    parts = [procedural.transform_mesh(read_mesh(m.mesh_path), m.matrix) for m in desc.collider_meshes()]
    return procedural.concatenate(parts)


def test_builtin_scene_names():
    assert {"room", "room2", "kiva"} <= set(scenes.builtin_scenes())


# What README.md's "Built-in scenes" promises: a declared stage's height is the surface under its
# centre within 1 mm; anywhere on any stage the surface is within 4 mm of it (a found stage's level
# spans 4 mm of height, kiva's bin floors are ribbed). Objects are dropped from above that height.
DECLARED_TOL = 0.001
ANYWHERE_TOL = 0.004
# Every built-in scene, as the code lists it; random_room draws a room per seed (two of them).
EVERY_SCENE = [(n, None) for n in scenes.builtin_scenes() if n != "random_room"] + [("random_room", 3), ("random_room", 8)]


@pytest.mark.filterwarnings("ignore::UserWarning")  # library models with missing maps say so
@pytest.mark.parametrize(("name", "variant"), EVERY_SCENE, ids=[f"{n}{'' if v is None else v}" for n, v in EVERY_SCENE])
def test_builtin_scene_stages_sit_on_geometry(name, variant, tmp_path):
    desc = scenes.load_scene(name, tmp_path, None, clearance=0.5, variant=variant)  # the install's mesh cache
    declared = scenes.declares_stages(name, tmp_path)
    assert len(desc.stages) >= (5 if declared else 2) and desc.lights and desc.meshes
    for m in desc.meshes:
        assert Path(m.mesh_path).is_file() and m.obj_id is None
        if m.material.texture:
            assert Path(m.material.texture).is_file()
    world = _world_mesh(desc)
    rng = np.random.default_rng(0)
    for st in desc.stages.values():
        assert st.area > 0.03, st.name
        # The surface right under the centroid and 24 random inner points, by rays cast from 3 cm
        # above (a shelf board overhead does not count).
        pts = [st.centroid] + [st.sample_point(rng) for _ in range(24)]
        z = procedural.ray_down(world.vertices, world.faces, pts, st.height + 0.03)
        if declared:
            assert abs(z[0] - st.height) <= DECLARED_TOL, (name, st.name, z[0], st.height)
        assert np.all(np.abs(z - st.height) <= ANYWHERE_TOL), (name, st.name, st.height, z)
        # Nothing intrudes into the first 10 cm above the stage (objects must fit).
        above = procedural.ray_down(world.vertices, world.faces, pts, st.height + 0.10)
        assert np.all(above <= st.height + ANYWHERE_TOL), (name, st.name, above)
    # Physically plausible light power (Blender semantics, see scenes.models).
    for light in desc.lights:
        if light.kind == "sun":
            assert 1.0 <= light.power <= 10.0
        else:
            assert 10.0 <= light.power <= 500.0


def test_stage_table_and_subset(tmp_path, cache):
    rows = scenes.stage_table("kiva")
    assert len(rows) == 12 and all(area > 0 and h > 0.5 for _, area, h in rows)
    desc = scenes.load_scene(SceneRef(name="kiva", stages=["bin_A", "bin_L"]), tmp_path, cache)
    assert list(desc.stages) == ["bin_A", "bin_L"]
    with pytest.raises(SceneError, match="bin_Z"):
        scenes.load_scene(SceneRef(name="kiva", stages=["bin_Z"]), tmp_path, cache)
    with pytest.raises(SceneError, match="built-in scenes are"):
        scenes.load_scene("nope", tmp_path, cache)


SCENE = """\
version: 1
name: mini
meshes:
  - name: ground
    source: {plane: [2, 2]}
    material: {texture: tex.png, uv_scale: 4}
  - name: block
    source: {box: [0.2, 0.2, 0.1]}
    transform: {translation: [0.5, 0.5, 0.05], rotation: [0, 0, 30], scale: [1, 2, 1]}
  - name: tube
    source: {cylinder: {radius: 0.1, height: 0.3}}
    transform: {translation: [-0.5, -0.5, 0.15]}
    collide: false
lights:
  - {kind: area, power: 100, translation: [0, 0, 2]}
  - {kind: spot, power: 50, translation: [1, 1, 2], look_at: [0, 0, 0]}
world: {color: [0.1, 0.1, 0.1]}
stages:
  - {name: ground, height: 0.0, polygon: [[-0.9, -0.9], [-0.9, 0.9], [0.9, 0.9], [0.9, -0.9]]}
  - {name: block_top, height: 0.1, polygon: [[0.47, 0.45], [0.53, 0.45], [0.53, 0.55], [0.47, 0.55]]}
"""


def _write_scene(tmp_path, text=SCENE):
    from PIL import Image

    Image.new("RGB", (8, 8), (200, 100, 50)).save(tmp_path / "tex.png")
    p = tmp_path / "mini.yaml"
    p.write_text(text)
    return p


def test_a_uv_scale_past_the_float_limit_is_refused(tmp_path, cache):
    """A 2 m plane at 6000 repeats per metre reaches 12,000 repeats: past UV_LIMIT, where float32
    keeps no position within a texel; said with the mesh and field, not repaired to a flat colour."""
    _write_scene(tmp_path, SCENE.replace("uv_scale: 4}", "uv_scale: 6000}"))
    with pytest.raises(SceneError, match=r"ground.*uv_scale: 6000 puts texture coordinates at 1\.2e\+04 repeats"):
        scenes.load_scene(SceneRef(file="mini.yaml"), tmp_path, cache)
    _write_scene(tmp_path, SCENE.replace("uv_scale: 4}", "uv_scale: 4000}"))  # 8,000: within
    scenes.load_scene(SceneRef(file="mini.yaml"), tmp_path, cache)


def test_user_scene_file(tmp_path, cache):
    _write_scene(tmp_path)
    ref = SceneRef(file="mini.yaml")
    desc = scenes.load_scene(ref, tmp_path, cache)
    assert desc.colliders == ("ground", "block")
    ground = read_mesh(desc.meshes[0].mesh_path)
    assert ground.uv.max() == pytest.approx(8.0)  # 2 m plane, 4 repeats per metre
    assert desc.meshes[0].material.texture.endswith("tex.png")
    block = desc.meshes[1]
    np.testing.assert_allclose(read_mesh(block.mesh_path).bounds[1], [0.1, 0.2, 0.05], atol=1e-6)  # scale baked in
    R = block.matrix[:3, :3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-6)  # poses stay rigid
    spot = desc.lights[1]
    d = -spot.matrix[:3, 2]  # emits along local -Z, towards the target
    np.testing.assert_allclose(d, -np.array([1, 1, 2]) / np.sqrt(6), atol=1e-9)
    world = _world_mesh(desc)
    st = desc.stages["block_top"]
    assert procedural.ray_down(world.vertices, world.faces, [st.centroid], 1.0)[0] == pytest.approx(0.1, abs=1e-6)
    # Fingerprint: stable, changes with the file and with referenced files.
    f1 = scenes.scene_fingerprint(ref, tmp_path)
    assert f1 == scenes.scene_fingerprint(ref, tmp_path)
    from PIL import Image

    Image.new("RGB", (8, 8), (10, 100, 50)).save(tmp_path / "tex.png")
    import os

    os.utime(tmp_path / "tex.png", ns=(0, 10**18))
    assert scenes.scene_fingerprint(ref, tmp_path) != f1
    assert scenes.scene_fingerprint("room", tmp_path) == scenes.scene_fingerprint("room", tmp_path)


@pytest.mark.parametrize(
    "edit, needle",
    [
        (("uv_scale: 4", "uv_scale: 4, roughness: 2"), r"mini\.yaml:6:\d+: meshes\.0\.material\.roughness"),
        (("power: 100", "power: -1"), r"mini\.yaml:\d+:\d+: lights\.0\.power"),
        (("{plane: [2, 2]}", "{sphere: 1}"), r"meshes\.0\.source"),
        (("collide: false", "colide: false"), r"meshes\.2\.colide.*[Ee]xtra"),
        (("world: {color: [0.1, 0.1, 0.1]}", "world: {color: [0.1, 0.1, 0.1], envmap: studio}"), r"world.*exactly one"),
        (("[0.9, -0.9]]}", "[0.9, -0.9]]}\n  - {name: ground, height: 0, polygon: [[0,0],[1,0],[0,1]]}"), r"stage name 'ground'"),
    ],
)
def test_scene_validation_errors_name_file_and_field(tmp_path, cache, edit, needle):
    old, new = edit
    assert old in SCENE
    _write_scene(tmp_path, SCENE.replace(old, new, 1))
    with pytest.raises(SceneError, match=needle):
        scenes.load_scene(SceneRef(file="mini.yaml"), tmp_path, cache)


def test_scene_missing_files_name_them(tmp_path, cache):
    _write_scene(tmp_path, SCENE.replace("{plane: [2, 2]}", "meshes/nope.obj", 1))
    with pytest.raises(SceneError, match=r"mini\.yaml: meshes\.ground.*nope\.obj"):
        scenes.load_scene(SceneRef(file="mini.yaml"), tmp_path, cache)
    _write_scene(tmp_path, SCENE.replace("tex.png", "missing.png", 1))
    with pytest.raises(SceneError, match="missing.png"):
        scenes.load_scene(SceneRef(file="mini.yaml"), tmp_path, cache)

"""Domain randomisation of any scene (materials, lights) and distractor objects: seed-locked, real
scenes, real physics, real annotation, real renders (photo backend: fast, and it draws no scene,
so its labels must ignore distractors; the flat example plugin draws them)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from specsynth.assets.library import textures
from specsynth.assets.library.cache import cache_dir
from specsynth.assets.library.realsets import resolve_ref
from specsynth.model.records import ArrangementRecord
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.run.store import Store
from specsynth.run.worker import World, distractor_name
from specsynth.scenes import load_scene
from specsynth.scenes.randomize import randomize_scene
from specsynth.spec.models import SceneRandomization
from specsynth.spec.yamlio import SpecError, load_spec

SPEC = """\
name: dr
seed: 11
intrinsics: {width: 96, height: 72, fx: 86.0, fy: 86.0, cx: 47.5, cy: 35.5}
objects:
  builtin: [duck, mug]
scenes:
  - name: room
    randomize: {materials: 1.0, roughness: 0.2, light_temperature: [2700, 6500], light_strength: [0.5, 2.0],
                light_position: 0.3}
arrangements:
  count: 2
  distractors: {count: [4, 4], objects: ["random_urdfs/*", teddy]}
cameras: {per_arrangement: 2, distance: [0.35, 0.6]}
backend: {name: photo}
outputs: {image_format: png}
"""

OPTS = SceneRandomization(materials=1.0, roughness=0.2, light_temperature=(2700, 6500), light_strength=(0.5, 2.0),
                          light_position=0.3, environment_strength=(0.5, 1.5))


def _variant(seed: int):
    scene = load_scene("room", Path(".")).with_objects(())
    lib = textures.available(cache_dir())
    return scene, randomize_scene(scene, OPTS, np.random.default_rng(seed), lib, lambda p: True)


def test_randomisation_is_seed_locked_and_leaves_geometry_alone():
    scene, a = _variant(1)
    _, b = _variant(1)
    _, c = _variant(2)
    assert a == b and a != c
    assert [(m.name, m.mesh_path, m.pose) for m in a.meshes] == [(m.name, m.mesh_path, m.pose) for m in scene.meshes]
    lib = {str(t.path) for t in textures.available(cache_dir())}
    assert all(m.material.texture in lib for m in a.meshes)  # materials: 1.0 swaps every surface
    assert {m.material.texture for m in a.meshes} != {m.material.texture for m in c.meshes}
    for before, after in zip(scene.lights, a.lights):
        moved = np.abs(np.asarray(after.pose)[:3, 3] - np.asarray(before.pose)[:3, 3])
        assert moved.max() <= 0.3 + 1e-9 and 0.5 * before.power - 1e-9 <= after.power <= 2.0 * before.power + 1e-9
        assert max(after.color) == pytest.approx(1.0)  # a black body, normalised
    assert a.world.strength != scene.world.strength
    off = randomize_scene(scene, SceneRandomization(), np.random.default_rng(1), [], lambda p: True)
    assert off is scene  # off by default: not even a copy


def test_lights_cutouts_and_glass_keep_their_materials_when_surfaces_are_swapped():
    """A texture swap would darken a glowing screen, fill a leaf's cut-out quad and make glass
    opaque: such surfaces keep their materials, and the others' draws do not move."""
    from dataclasses import replace

    from specsynth.model.ir import MaterialIR

    scene = load_scene("room", Path(".")).with_objects(())
    special = (MaterialIR(emission=(4.0, 4.0, 4.0)), MaterialIR(alpha_mode="mask", opacity_texture="leaf.png"),
               MaterialIR(transmission=1.0, roughness=0.0), MaterialIR(opacity=0.5, alpha_mode="blend"))
    meshes = list(scene.meshes)
    for k, mat in enumerate(special):
        meshes[k] = replace(meshes[k], material=mat)
    plain = replace(scene, meshes=tuple(meshes))
    lib = textures.available(cache_dir())
    out = randomize_scene(plain, OPTS, np.random.default_rng(3), lib, lambda p: True)
    ref = randomize_scene(scene, OPTS, np.random.default_rng(3), lib, lambda p: True)
    for k, mat in enumerate(special):
        got = out.meshes[k].material
        assert got.texture is None and got.emission == mat.emission and got.alpha_mode == mat.alpha_mode
        assert got.opacity_texture == mat.opacity_texture and got.transmission == mat.transmission
    assert out.meshes[len(special):] == ref.meshes[len(special):]
    assert all(m.material.texture in {str(t.path) for t in lib} for m in out.meshes[len(special):])


def test_distractors_are_scene_geometry_and_never_annotated(tmp_path):
    f = tmp_path / "dr.yaml"
    f.write_text(SPEC)
    g = compile_spec(load_spec(f))
    s = build(g, tmp_path / "out", jobs=1)
    assert not s.failures, s.failures
    store = Store(tmp_path / "out")
    recs = [ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange")]
    assert sum(len(r.distractors) for r in recs) >= 4  # 8 dropped; a few may leave the stage
    assert all(d.name == "teddy" or d.name.startswith("random_urdfs/") for r in recs for d in r.distractors)
    world = World(g.inputs.arrange, f.parent)
    scene = world.render_scene(recs[0])
    extra = [m for m in scene.meshes if m.name.startswith("distractor_")]
    assert len(extra) == len(recs[0].distractors) and all(m.obj_id is None for m in extra)
    assert world.render_scene(recs[0]) == scene  # randomisation is a function of the arrangement
    gt = json.loads((tmp_path / "out" / "bop" / "train_pbr" / "000000" / "scene_gt.json").read_text())
    assert {i["obj_id"] for v in gt.values() for i in v} <= {1, 2}  # only the dataset objects
    n_objects = {r.arr: len(r.objects) for r in recs}
    assert all(len(v) == n_objects[int(k) // 2] for k, v in gt.items())
    # Every swapped-in texture of every arrangement is credited, by name.
    lib = {str(t.path): t.name for t in textures.available(cache_dir())}
    world = World(g.inputs.arrange, f.parent)
    swapped = {lib[m.material.texture] for r in recs for m in world.render_scene(r).meshes if m.material.texture in lib}
    att = json.loads((tmp_path / "out" / "attribution.json").read_text())
    credited = {a["asset"].removeprefix("texture:") for a in att if a["asset"].startswith("texture:")}
    assert swapped and swapped <= credited, sorted(swapped - credited)


def test_unknown_distractor_is_a_located_error(tmp_path):
    f = tmp_path / "dr.yaml"
    f.write_text(SPEC.replace("teddy]", "teddyy]"))
    with pytest.raises(SpecError) as e:
        compile_spec(load_spec(f))
    (pr,) = e.value.problems
    assert pr.line == 12 and pr.path == "arrangements.distractors.objects.1" and "teddyy" in pr.message


def test_distractors_annotated_on_request(tmp_path):
    """distractors.annotate: the distractors become objects of the dataset, under stable obj_ids
    after the spec's, with their models in bop/models, masks and gt like any object, and credited."""
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    spec = ["arrangements.distractors={count: [3, 3], objects: [teddy, 'random_urdfs/*'], annotate: true}"]
    result = build(compile_spec(load_spec(f, spec)), tmp_path / "out", jobs=1)
    assert not result.failures and result.images >= 1
    chunk = tmp_path / "out" / "bop" / "train_pbr" / "000000"
    n_objects = len(load_spec(f).spec.objects.builtin)
    gts = json.loads((chunk / "scene_gt.json").read_text())
    extra = {g["obj_id"] for im in gts.values() for g in im if g["obj_id"] > n_objects}
    assert extra, "no distractor annotated"
    models = json.loads((tmp_path / "out" / "bop" / "models" / "models_info.json").read_text())
    assert extra <= {int(k) for k in models}
    d = load_spec(f, spec).spec.arrangements.distractors
    for obj_id in extra:
        name = d.name_of(obj_id, n_objects)
        assert d.obj_id(name, n_objects) == obj_id and (name == "teddy" or name.startswith("random_urdfs/"))
    credits = json.loads((tmp_path / "out" / "attribution.json").read_text())
    assert any("random_urdfs" in c.get("source", "") or c.get("name") == "teddy" for c in credits)
    for im, entries in gts.items():
        assert len(list(chunk.glob(f"mask/{int(im):06d}_*.png"))) == len(entries)


def test_catalogue_items_are_objects_sized_coloured_and_credited(tmp_path):
    """A small furniture-library model as a built-in object (distractor or target): its own mesh
    (two models of one archive differ), its catalogue size, BOP's origin at the box centre, its
    parts' colours as vertex colours, the library's credit."""
    from specsynth.assets.library import furniture
    from specsynth.assets.meshio import read_mesh
    from specsynth.assets.resolve import catalogue_objects, resolve_objects
    from specsynth.spec.models import Objects

    names = catalogue_objects()
    assert len(names) >= 150 and all(n.startswith("catalogue/") for n in names)
    picks = ["catalogue/Scopia#teapot", "catalogue/Scopia#sandwichMaker"]  # one archive
    assets = resolve_objects(Objects(builtin=picks), tmp_path, tmp_path / "cache")
    assert len({a.mesh_key for a in assets}) == 2
    for a, name in zip(assets, picks):
        item = furniture.find(name.removeprefix("catalogue/"))
        w, d, h = item.size
        assert a.extents == pytest.approx((w, d, h), rel=1e-3)
        mesh = read_mesh(a.mesh_path)
        assert np.allclose((mesh.vertices.min(0) + mesh.vertices.max(0)) / 2, 0, atol=1e-5)
        assert mesh.colors is not None and a.material.use_vertex_colors and mesh.uv is None
        assert a.credit == item.credit


def test_catalogue_distractors_drop_render_and_are_credited(tmp_path):
    """'catalogue/*' drops the library's small items (cups, books, toys) among the objects:
    settled by physics, drawn, unannotated, credited; an annotated wildcard and an unknown item
    are located errors."""
    f = tmp_path / "dr.yaml"
    f.write_text(SPEC.replace('objects: ["random_urdfs/*", teddy]', 'objects: ["catalogue/*"]')
                 .replace("backend: {name: photo}", "backend: {name: flat}"))
    s = build(compile_spec(load_spec(f)), tmp_path / "out", jobs=1)
    assert not s.failures, s.failures
    store = Store(tmp_path / "out")
    recs = [ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange")]
    dropped = {d.name for r in recs for d in r.distractors}
    assert len(dropped) >= 3 and all(n.startswith("catalogue/") for n in dropped)
    credited = {c["asset"] for c in json.loads((tmp_path / "out" / "attribution.json").read_text())}
    assert {"furniture:" + n.removeprefix("catalogue/") for n in dropped} <= credited
    gt = json.loads((tmp_path / "out" / "bop" / "train_pbr" / "000000" / "scene_gt.json").read_text())
    assert {i["obj_id"] for v in gt.values() for i in v} <= {1, 2}
    f.write_text(SPEC.replace('objects: ["random_urdfs/*", teddy]', 'objects: ["catalogue/*"], annotate: true'))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    assert e.value.problems[0].line == 12 and "catalogue/<id>" in e.value.problems[0].message
    f.write_text(SPEC.replace('objects: ["random_urdfs/*", teddy]', 'objects: ["catalogue/Scopia#teapott"]'))
    with pytest.raises(SpecError) as e:
        compile_spec(load_spec(f))
    (pr,) = e.value.problems
    assert pr.path == "arrangements.distractors.objects.0" and "teapott" in pr.message


def test_a_distractor_drawn_twice_is_dropped_twice_by_a_cold_worker(tmp_path):
    """The same model twice in one arrangement: a fresh worker (nothing cached) resolves it once
    and drops it twice, so the dataset does not depend on which worker ran the job."""
    f = tmp_path / "dr.yaml"
    f.write_text(SPEC)
    g = compile_spec(load_spec(f))
    assets = World(g.inputs.arrange, f.parent).distractor_assets(["teddy", "random_urdfs/007", "teddy"])
    assert [a.name for a in assets] == ["teddy", "random_urdfs/007", "teddy"] and assets[0] is assets[2]


PAINTED = SPEC.replace('objects: ["random_urdfs/*", teddy]}', 'objects: [teddy, toys/cube], paint: 1.0, paint_saturation: [0.3, 0.4], annotate: true}') \
    .replace("builtin: [duck, mug]", "builtin: [mug]").replace("image_format: png}", "image_format: png, albedo: true}") \
    .replace("  - name: room\n    randomize: {materials: 1.0, roughness: 0.2, light_temperature: [2700, 6500], "
             "light_strength: [0.5, 2.0],\n                light_position: 0.3}\n", "  - name: room\n")


def test_painted_distractors_are_drawn_in_their_colour(tmp_path):
    """distractors.paint: each painted distractor is one plastic colour of the spec's saturation,
    kept in its record, and drawn in it (its albedo under its own mask is that colour); paint 0
    draws nothing."""
    import colorsys

    from specsynth.model.colour import linear_to_srgb

    f = tmp_path / "dr.yaml"
    f.write_text(PAINTED)
    s = build(compile_spec(load_spec(f)), tmp_path / "out", jobs=1)
    assert not s.failures, s.failures
    store = Store(tmp_path / "out")
    recs = {r.arr: r for r in (ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange"))}
    painted = [o for r in recs.values() for o in r.objects if o.obj_id > 1]
    assert len(painted) >= 4 and all(o.color is not None for o in painted)
    assert len({tuple(o.color) for o in painted}) == len(painted)  # each its own colour
    assert all(0.3 - 1e-6 <= colorsys.rgb_to_hsv(*linear_to_srgb(np.asarray(o.color)))[1] <= 0.4 + 1e-6
               for o in painted)
    assert all(o.color is None for r in recs.values() for o in r.objects if o.obj_id == 1)
    chunk = tmp_path / "out" / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    checked = 0
    for im, insts in gt.items():
        albedo = np.asarray(Image.open(chunk / "albedo" / f"{int(im):06d}.png")).astype(float)
        objects = recs[int(im) // 2].objects
        for k, inst in enumerate(insts):
            mask = np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{k:06d}.png")) > 0
            if inst["obj_id"] == 1 or mask.sum() < 30:
                continue
            want = 255 * linear_to_srgb(np.asarray(objects[k].color))
            assert np.abs(np.median(albedo[mask], axis=0) - want).max() < 3
            checked += 1
    assert checked >= 2
    f.write_text(PAINTED.replace("paint: 1.0", "paint: 0.0"))
    s = build(compile_spec(load_spec(f)), tmp_path / "plain", jobs=1)
    store = Store(tmp_path / "plain")
    assert all(o.color is None for k in store.keys("arrange")
               for o in ArrangementRecord.from_json(store.load("arrange", k)).objects)


def test_painted_distractors_keep_their_paint_through_randomised_materials(tmp_path):
    """Unannotated distractors are scene geometry, whose materials randomisation swaps for library
    textures (materials: 1.0): a painted one is drawn in its paint all the same, a plastic (not
    metal), with the randomised roughness kept."""
    f = tmp_path / "dr.yaml"
    f.write_text(SPEC.replace('objects: ["random_urdfs/*", teddy]}', 'objects: ["random_urdfs/*", teddy], paint: 1.0}'))
    g = compile_spec(load_spec(f))
    s = build(g, tmp_path / "out", jobs=1)
    assert not s.failures, s.failures
    store = Store(tmp_path / "out")
    world = World(g.inputs.arrange, f.parent)
    checked = 0
    for k in store.keys("arrange"):
        rec = ArrangementRecord.from_json(store.load("arrange", k))
        meshes = {m.name: m for m in world.render_scene(rec).meshes}
        for n, d in enumerate(rec.distractors):
            m = meshes[distractor_name(n)].material
            assert d.color is not None and m.base_color == pytest.approx(tuple(d.color))
            assert m.texture is None and not m.use_vertex_colors and m.metallic == 0.0
            checked += 1
    assert checked >= 4


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), share=st.floats(0.0, 1.0),
       saturation=st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0)).map(sorted))
def test_paint_colour_is_a_plastic_colour_drawn_with_its_share(seed, share, saturation):
    import colorsys

    from specsynth.model.colour import linear_to_srgb
    from specsynth.run.arrange import PLASTIC_HUE_JITTER, PLASTIC_HUES, paint_color

    rng = np.random.default_rng(seed)
    colours = [paint_color(share, rng, tuple(saturation)) for _ in range(200)]
    if share == 0.0:
        assert all(c is None for c in colours)
        assert rng.random() == np.random.default_rng(seed).random()  # nothing drawn
        return
    painted = [c for c in colours if c is not None]
    assert abs(len(painted) / 200 - share) < 0.2
    for c in painted:
        h, s, v = colorsys.rgb_to_hsv(*linear_to_srgb(np.asarray(c)))
        assert saturation[0] - 1e-6 <= s <= saturation[1] + 1e-6 and 0.6 - 1e-6 <= v <= 1.0 + 1e-6
        if s < 1e-3:
            continue  # a grey has no hue
        # a toy's hue: within the jitter of one of the palette's (on the hue circle)
        assert min(abs((h - hue + 0.5) % 1.0 - 0.5) for hue, _ in PLASTIC_HUES) <= PLASTIC_HUE_JITTER + 1e-4


FOLDER_SPEC = SPEC.replace('distractors: {count: [4, 4], objects: ["random_urdfs/*", teddy]}',
                           'distractors: {count: [3, 3], paths: [MODELS]}').replace(
    "backend: {name: photo}", "backend: {name: flat}")


def _folder_spec(tmp_path: Path, models: str) -> Path:
    f = tmp_path / "dr.yaml"
    f.write_text(FOLDER_SPEC.replace("MODELS", models))
    return f


def test_distractors_from_a_bop_folder_drop_render_and_are_not_annotated(tmp_path):
    """The BOP recipes' distractors from another dataset: a BOP models folder's models drawn, settled
    by physics, drawn in the scene (occluding), never annotated; the list alone, without the
    built-in shapes."""
    from specsynth.assets import bopdistractors

    f = _folder_spec(tmp_path, "dataset:lmo/models")
    g = compile_spec(load_spec(f))
    assert g.spec.arrangements.distractors.objects == []
    s = build(g, tmp_path / "out", jobs=1)
    assert not s.failures, s.failures
    store = Store(tmp_path / "out")
    recs = [ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange")]
    dropped = [d for r in recs for d in r.distractors]
    assert len(dropped) >= 4  # 6 dropped; one may leave the stage
    assert {bopdistractors.parse(d.name)[0] for d in dropped} == {0}
    assert {bopdistractors.parse(d.name)[1] for d in dropped} <= {1, 5, 6, 8, 9, 10, 11, 12}
    assert all(np.asarray(d.pose)[2, 3] > -1.0 for d in dropped)
    world = World(g.inputs.arrange, f.parent)
    extra = [m for m in world.render_scene(recs[0]).meshes if m.name.startswith("distractor_")]
    assert len(extra) == len(recs[0].distractors) and all(m.obj_id is None for m in extra)
    from specsynth.assets.meshio import read_mesh

    ape = read_mesh(extra[0].mesh_path).vertices  # millimetres read as metres would be 1000 times larger
    assert 0.02 < float(np.ptp(ape, axis=0).max()) < 0.3
    gt = json.loads((tmp_path / "out" / "bop" / "train_pbr" / "000000" / "scene_gt.json").read_text())
    assert {i["obj_id"] for v in gt.values() for i in v} <= {1, 2}


def test_a_distractor_folders_bytes_key_the_arrangements_and_its_errors_are_located(tmp_path):
    lmo = Path(resolve_ref("dataset:lmo/models", cache_dir()))
    mine = tmp_path / "models"
    shutil.copytree(lmo, mine)
    f = _folder_spec(tmp_path, "models")
    before = compile_spec(load_spec(f)).arrange_job(0).key
    with (mine / "obj_000005.ply").open("ab") as fh:
        fh.write(b"\n")
    assert compile_spec(load_spec(f)).arrange_job(0).key != before
    f.write_text(FOLDER_SPEC.replace("MODELS", "nowhere"))
    with pytest.raises(SpecError) as e:
        compile_spec(load_spec(f))
    (pr,) = e.value.problems
    assert pr.line == 12 and pr.path == "arrangements.distractors.paths.0" and "nowhere" in pr.message
    (tmp_path / "afile").write_text("x")
    for given, said in (("afile", "is not a folder"), ("dataset:nope/models", "no installed dataset 'nope'")):
        f.write_text(FOLDER_SPEC.replace("MODELS", given))
        with pytest.raises(SpecError) as e:
            compile_spec(load_spec(f))
        assert said in e.value.problems[0].message and not e.value.problems[0].message.startswith("arrangements")
    f.write_text(FOLDER_SPEC.replace("MODELS", "models").replace("paths: [models]", "paths: [models], annotate: true"))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    assert e.value.problems[0].line == 12 and "annotate" in e.value.problems[0].message
    f.write_text(FOLDER_SPEC.replace("paths: [MODELS]", "objects: []"))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    assert "objects or paths" in e.value.problems[0].message

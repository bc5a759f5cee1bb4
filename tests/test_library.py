"""The asset library (Sweet Home 3D furniture, robosuite textures), library furniture in scenes,
``random_room`` and the attribution file, on the real installed assets (make install)."""

from __future__ import annotations

import re

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from specsynth.assets.library import furniture, textures
from specsynth.assets.meshio import read_mesh
from specsynth.scenes import SceneError, load_scene
from specsynth.scenes.random_room import random_room
from specsynth.spec.models import SceneRef

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning")  # library models with missing maps say so


@pytest.fixture()
def cache(tmp_path, monkeypatch) -> Path:
    """A fresh mesh cache that still sees the installed textures (make install put them in the real one)."""
    from specsynth.assets.resolve import cache_dir

    real = cache_dir()
    c = tmp_path / "cache"
    (c / "library").mkdir(parents=True)
    (c / "library" / textures.FOLDER).symlink_to(textures.folder(real))
    monkeypatch.setenv("SPECSYNTH_CACHE", str(c))
    return c


def test_catalogue_reads_every_archive_with_sizes_and_licences():
    items = furniture.catalogue()
    assert len(items) >= 800
    by_id = {i.id: i for i in items}
    chair = by_id["Blend Swap CC-0#armchair"]
    assert chair.size == pytest.approx((0.594, 0.627, 1.05)) and chair.drop_on_top == pytest.approx(0.421)
    assert chair.licence == "CC0-1.0" and chair.creator == "Absfrm"
    assert {i.licence for i in items} == {"CC0-1.0", "CC-BY-3.0", "CC-BY-3.0-US"}
    assert sum(i.rotation is not None for i in items) > 10 and sum(i.door_or_window for i in items) > 10
    with pytest.raises(furniture.LibraryError, match="did you mean"):
        furniture.find("Blend Swap CC-0#armchiar")


def test_library_missing_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("SPECSYNTH_SH3D_DIR", str(tmp_path))
    with pytest.raises(furniture.LibraryError, match="install the Debian package sweethome3d-furniture"):
        furniture.catalogue()


def test_extraction_is_once_with_a_manifest_and_brings_shared_textures(tmp_path):
    item = furniture.find("Scopia#bar_chair")  # its MTL names a texture kept in bar_table's folder
    obj = furniture.extract(item, tmp_path)
    manifest = json.loads((obj.parent / "manifest.json").read_text())["files"]
    assert obj.name in manifest and "wood_table_chairs.jpg" in manifest
    import hashlib

    assert all(hashlib.sha256((obj.parent / n).read_bytes()).hexdigest() == h for n, h in manifest.items())
    mtime = obj.stat().st_mtime_ns
    assert furniture.extract(item, tmp_path) == obj and obj.stat().st_mtime_ns == mtime


def test_textures_are_installed_with_kinds(cache):
    kinds = {t.kind for t in textures.available(cache)}
    assert {"floor", "wall", "worktop"} <= kinds and len(textures.available(cache)) >= 20
    assert textures.of_kind(cache, "floor")[0].credit["licence"] == "MIT"


def test_textures_not_installed_is_a_clear_error(tmp_path):
    with pytest.raises(textures.TextureLibraryError, match="run `make install`"):
        textures.available(tmp_path)


def test_library_furniture_is_sized_and_stands_on_the_floor(tmp_path, cache):
    (tmp_path / "s.yaml").write_text(
        "version: 1\nname: s\nmeshes:\n"
        "  - {name: floor, source: {plane: [4, 4]}}\n"
        "  - {name: t, source: {furniture: 'Scopia#table_wood_and_iron'}, transform: {translation: [0.5, 0, 0], rotation: [0, 0, 90]}}\n"
    )
    desc = load_scene(SceneRef(file=str(tmp_path / "s.yaml")), tmp_path, cache=cache)
    parts = [m for m in desc.meshes if m.name.startswith("t/")]
    v = np.concatenate([read_mesh(m.mesh_path).vertices for m in parts])
    w, d, h = furniture.find("Scopia#table_wood_and_iron").size
    assert np.ptp(v, axis=0) == pytest.approx((w, d, h), rel=0.01)
    assert v[:, 2].min() == pytest.approx(0.0, abs=1e-5) and v[:, :2].mean(0) == pytest.approx((0, 0), abs=0.15)
    assert any(np.allclose(m.matrix[:3, 3], (0.5, 0, 0)) for m in parts)
    assert [c["asset"] for c in desc.credits] == ["furniture:Scopia#table_wood_and_iron"]
    assert any(s.height == pytest.approx(0.503, abs=0.01) for s in desc.stages.values())  # its top


def test_random_room_is_seed_locked_furnished_and_never_overlapping(cache):
    a, credits_a = random_room(11, cache)
    b, _ = random_room(11, cache)
    c, _ = random_room(12, cache)
    assert a.model_dump() == b.model_dump() and a.model_dump() != c.model_dump()
    furn = [m for m in a.meshes if m.name.startswith("furniture_")]
    assert len(furn) >= 5
    listed = {c["asset"] for c in credits_a}
    assert {f"furniture:{m.source.furniture}" for m in furn} <= listed
    assert sum(a.startswith("texture:") for a in listed) >= 2  # the floor's and the walls' at least
    for m in furn:  # re-dressed materials exist in the model and use installed textures
        for name, mat in m.materials.items():
            assert Path(mat.texture).is_file() and name
    floor = next(m for m in a.meshes if m.name == "floor")
    W, D = floor.source.plane
    boxes = []
    for m in furn:
        w, d, _ = furniture.find(m.source.furniture).size
        yaw = m.transform.rotation[2]
        if abs(abs(yaw) - 90) < 1:
            w, d = d, w
        x, y, _ = m.transform.translation
        boxes.append((x - w / 2, y - d / 2, x + w / 2, y + d / 2))
        assert -W / 2 - 1e-6 <= x - w / 2 and x + w / 2 <= W / 2 + 1e-6 and -D / 2 - 1e-6 <= y - d / 2 and y + d / 2 <= D / 2 + 1e-6
    for i in range(len(boxes)):
        for j in range(i):
            p, q = boxes[i], boxes[j]
            assert not (p[0] < q[2] and q[0] < p[2] and p[1] < q[3] and q[1] < p[3]), (i, j)


def test_random_room_loads_with_stages_on_furniture(cache):
    desc = load_scene("random_room", Path("."), cache=cache, variant=3, clearance=0.7)
    assert len(desc.stages) >= 2 and any(s.height > 0.3 for s in desc.stages.values())
    assert desc.world.kind in ("envmap", "color") and len(desc.lights) >= 2
    assert any(m.material.texture for m in desc.meshes if m.name == "floor")
    again = load_scene("random_room", Path("."), cache=cache, variant=3, clearance=0.7)
    assert [(m.name, m.mesh_key, m.pose) for m in again.meshes] == [(m.name, m.mesh_key, m.pose) for m in desc.meshes]


@pytest.mark.parametrize("name", ["living_room", "kitchen", "office", "bedroom", "workshop", "shop"])
def test_fixed_furnished_rooms(name, cache):
    """The paper's fixed furnished scenes in spirit: ten or more library models, textured floor and
    walls, a window onto an HDRI sky, three lights, stages on furniture tops; the same every load."""
    from specsynth.scenes import builtin_scenes
    from specsynth.scenes.random_room import fixed_room

    assert name in builtin_scenes()
    sf, credits = fixed_room(name, cache)
    furn = [m for m in sf.meshes if m.name.startswith("furniture_")]
    assert len(furn) >= 10 and len({m.source.furniture for m in furn}) >= 6
    assert any(m.name == "wall_north_below" for m in sf.meshes)  # the window opening
    desc = load_scene(name, Path("."), cache=cache, clearance=0.5)
    assert desc.world.kind == "envmap" and len(desc.lights) >= 3
    for surface in ("floor", "wall_south"):
        assert next(m for m in desc.meshes if m.name.startswith(surface)).material.texture
    tops = [s for s in desc.stages.values() if s.height > 0.3]
    assert len(tops) >= 2, sorted((s.name, s.height) for s in desc.stages.values())
    assert {f"furniture:{m.source.furniture}" for m in furn} <= {c["asset"] for c in desc.credits}
    again = load_scene(name, Path("."), cache=cache, clearance=0.5)
    assert [(m.name, m.mesh_key, m.pose) for m in again.meshes] == [(m.name, m.mesh_key, m.pose) for m in desc.meshes]


def test_random_room_parameters_from_the_spec(cache, tmp_path):
    ref = SceneRef(name="random_room", room={"kinds": ["workshop"], "width": [4.0, 4.0], "depth": [3.5, 3.5],
                                             "density": [1.5, 1.5]})
    desc = load_scene(ref, Path("."), cache=cache, variant=5, clearance=0.5)
    floor = next(m for m in desc.meshes if m.name == "floor")
    v = read_mesh(floor.mesh_path).vertices
    assert np.ptp(v[:, 0]) == pytest.approx(4.0, abs=1e-4) and np.ptp(v[:, 1]) == pytest.approx(3.5, abs=1e-4)
    from specsynth.scenes.random_room import kind_items

    ids = {i.id for i in kind_items("workshop")}
    used = {c["asset"].removeprefix("furniture:") for c in desc.credits if c["asset"].startswith("furniture:")}
    clutter = {i.id for i in furniture.small_items()}
    assert used & ids and used - ids <= clutter  # workshop furniture, and small items on its tops
    with pytest.raises(ValueError, match="for the scene 'random_room' only"):
        SceneRef(name="room", room={"kinds": ["shop"]})


def test_clutter_stands_on_open_tops_and_leaves_stages(cache):
    """Small catalogue items stand on tables, counters and cabinets (at the top's height, inside its
    footprint, apart from each other) and are credited, on the dressed work surfaces too; the rooms
    keep stages above the floor."""
    from specsynth.assets.library import furniture
    from specsynth.scenes.random_room import open_top, random_room

    small = {i.id for i in furniture.small_items()}
    seen = 0
    for seed in range(6):
        sf, credits = random_room(seed, cache)
        pieces = [(furniture.find(m.source.furniture), m.transform.translation) for m in sf.meshes
                  if m.name.startswith("furniture_")]
        for m in (m for m in sf.meshes if m.name.startswith("clutter_") or re.match(r"desk\d+_item_", m.name)):
            seen += 1
            assert m.source.furniture in small and m.collide
            assert f"furniture:{m.source.furniture}" in {c["asset"] for c in credits}
            x, y, z = m.transform.translation
            under = [(i, t) for i, t in pieces if open_top(i) is not None and abs(open_top(i) + 0.001 - z) < 1e-9
                     and abs(x - t[0]) < max(i.size[:2]) / 2 and abs(y - t[1]) < max(i.size[:2]) / 2]
            assert under, (seed, m.name)
    assert seen >= 6


def test_pictures_hang_on_the_walls_clear_of_window_furniture_and_each_other(cache):
    """Framed public-domain / CC0 photographs: against a wall's inner face, 1.1-1.9 m up, inside
    the wall, never over the window, over each other or over furniture reaching their bottom
    edge; credited; the same for a seed."""
    from specsynth.assets.library import pictures

    by_file = {p.path.name: p.name for p in pictures.available()}
    assert len(by_file) >= 5 and all(p.licence in ("CC0", "public domain") for p in pictures.available())
    hung = 0
    for seed in range(12):
        sf, credits = random_room(seed, cache)
        W, D = next(m for m in sf.meshes if m.name == "floor").source.plane
        H = next(m for m in sf.meshes if m.name == "ceiling").transform.translation[2] - 0.05
        win = next(m for m in sf.meshes if m.name == "wall_north_below")
        wx, ww = win.transform.translation[0], win.source.box[0]
        spans = []
        for m in (m for m in sf.meshes if m.name.startswith("picture_") and not m.name.endswith("_frame")):
            hung += 1
            assert f"picture:{by_file[Path(m.material.texture).name]}" in {c["asset"] for c in credits}
            x, y, z = m.transform.translation
            w, _, h = m.source.box
            yaw = m.transform.rotation[2]
            assert 1.1 <= z <= 1.9 and z + h / 2 < H and not m.collide
            wall = {0.0: "north", 180.0: "south", -90.0: "east", 90.0: "west"}[yaw]
            along, off = (x, y) if wall in ("north", "south") else (y, x)
            half = W / 2 if wall in ("north", "south") else D / 2
            assert abs(abs(off) - ((D if wall in ("north", "south") else W) / 2 - 0.02)) < 1e-9
            assert -half < along - w / 2 and along + w / 2 < half
            if wall == "north":
                assert along + w / 2 <= wx - ww / 2 or wx + ww / 2 <= along - w / 2
            spans.append((wall, along - w / 2, along + w / 2))
            strip = {"north": (along - w / 2, D / 2 - 0.6, along + w / 2, D / 2),
                     "south": (along - w / 2, -D / 2, along + w / 2, -D / 2 + 0.6),
                     "east": (W / 2 - 0.6, along - w / 2, W / 2, along + w / 2),
                     "west": (-W / 2, along - w / 2, -W / 2 + 0.6, along + w / 2)}[wall]
            for piece in (p for p in sf.meshes if p.name.startswith("furniture_")):
                fw, fd, fh = furniture.find(piece.source.furniture).size
                if abs(abs(piece.transform.rotation[2]) - 90) < 1:
                    fw, fd = fd, fw
                px, py, _ = piece.transform.translation
                if fh >= z - h / 2 - 0.05:  # reaches the picture: must stand clear of the wall below it
                    assert not (px - fw / 2 < strip[2] and strip[0] < px + fw / 2 and py - fd / 2 < strip[3]
                                and strip[1] < py + fd / 2), (seed, m.name, piece.name)
        for i in range(len(spans)):
            for j in range(i):
                a, b = spans[i], spans[j]
                assert a[0] != b[0] or a[2] <= b[1] or b[2] <= a[1], (seed, a, b)
        again, _ = random_room(seed, cache)
        assert again.model_dump() == sf.model_dump()
    assert hung >= 10


def test_plain_materials_whose_texture_file_is_lost_are_redressed(cache):
    """Blend Swap's bed2 names texture files its archive lacks: such a material renders plain, so it
    counts as untextured and gets a library texture as often as any plain one."""
    from specsynth.scenes.random_room import REDRESS, redress

    item = furniture.find("Blend Swap CC-0#bed2")
    woods = [t for t in textures.available(cache) if t.kind == "floor" and "wood" in t.name]
    felt = next(t for t in textures.available(cache) if t.kind == "fabric")
    dressed = [redress(np.random.default_rng(seed), item, cache, woods, felt)[0] for seed in range(40)]
    share = np.mean(["sheet" in d for d in dressed])
    assert abs(share - REDRESS) < 0.2 and all(Path(d["sheet"].texture).is_file() for d in dressed if "sheet" in d)


def test_random_room_without_textures_names_the_fix(tmp_path, monkeypatch):
    monkeypatch.setenv("SPECSYNTH_CACHE", str(tmp_path))
    with pytest.raises(SceneError, match="run `make install`"):
        load_scene("random_room", Path("."), cache=tmp_path, variant=1)


# --------------------------------------------------------------------------- builds and attribution


SPEC = """\
version: 1
name: rr
seed: 5
intrinsics: {width: 64, height: 48, fx: 57.0, fy: 57.0, cx: 32.0, cy: 24.0}
objects: {builtin: [duck, mug, jenga]}
scenes: [{name: random_room}]
arrangements: {count: 3}
cameras: {per_arrangement: 1, elevation: [30, 60], distance: [0.6, 1.2]}
backend: {name: photo}
outputs: {depth_scale: 0.25}
"""


def _build(spec: Path, out: Path):
    from specsynth.plan.compiler import compile_spec
    from specsynth.run.build import build
    from specsynth.spec.yamlio import load_spec

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return build(compile_spec(load_spec(spec)), out, jobs=1)


def want_credits(room, cache) -> set[str]:
    """What a room shows that needs a credit, found from its meshes (not from the generator's own
    credit list): library furniture and clutter, library textures, pictures."""
    from specsynth.assets.library import pictures

    by_picture = {str(p.path): p.name for p in pictures.available()}
    by_texture = {str(t.path): t.name for t in textures.available(cache)}
    want = set()
    for m in room.meshes:
        if getattr(m.source, "furniture", None):
            want.add(f"furniture:{m.source.furniture}")
        for mat in [m.material, *m.materials.values()]:
            if mat.texture in by_texture:
                want.add(f"texture:{by_texture[mat.texture]}")
            if mat.texture in by_picture:
                want.add(f"picture:{by_picture[mat.texture]}")
    return want


def test_random_room_build_has_a_room_per_arrangement_and_a_complete_attribution(tmp_path, cache):
    spec = tmp_path / "rr.yaml"
    spec.write_text(SPEC)
    out = tmp_path / "out"
    _build(spec, out)
    from specsynth.model.records import ArrangementRecord
    from specsynth.run.store import Store

    store = Store(out)
    arrs = [ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange")]
    assert len({a.scene for a in arrs}) == 3 and all(a.scene.startswith("random_room#") for a in arrs)
    listed = {c["asset"] for c in json.loads((out / "attribution.json").read_text())}
    import pyarrow.parquet as pq

    used = set(pq.read_table(out / "parquet" / "images.parquet", columns=["arr"]).column("arr").to_pylist())
    for a in arrs:
        if a.arr not in used:
            continue
        room, _ = random_room(a.scene_ref[1], cache)
        assert want_credits(room, cache) <= listed, want_credits(room, cache) - listed
    assert {"object:duck", "object:mug", "object:jenga"} <= listed
    md = (out / "ATTRIBUTION.md").read_text()
    assert "CC-BY" in md or "CC0" in md
    first = (out / "ATTRIBUTION.md").read_bytes()
    _build(spec, out)  # a rebuild writes the same attribution
    assert (out / "ATTRIBUTION.md").read_bytes() == first


def test_attribution_is_written_even_without_third_party_assets(tmp_path):
    from specsynth.outputs.attribution import write_attribution

    assert write_attribution(tmp_path, [], "d") == {"attribution_assets": 0}
    assert "(none)" in (tmp_path / "ATTRIBUTION.md").read_text()
    assert json.loads((tmp_path / "attribution.json").read_text()) == []


@pytest.mark.slow
@pytest.mark.parametrize("backend", ["cycles", "mitsuba"])
def test_random_room_renders_in_both_backends(tmp_path, cache, backend):
    spec = tmp_path / "rr.yaml"
    opts = "{name: cycles, samples: 4, denoise: true}" if backend == "cycles" else "{name: mitsuba, samples: 4}"
    spec.write_text(SPEC.replace("backend: {name: photo}", f"backend: {opts}").replace("count: 3", "count: 2"))
    out = tmp_path / "out"
    s = _build(spec, out)
    assert s.images >= 1
    from PIL import Image

    for p in (out / "bop/train_pbr/000000/rgb").iterdir():
        rgb = np.asarray(Image.open(p)).astype(float)
        assert 10 < rgb.mean() < 245 and rgb.std() > 8  # a lit, textured room: not black, not blank


def test_scenes_json_lists_every_builtin_scene(capsys):
    from specsynth.cli import main

    assert main(["scenes", "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert {"room", "room2", "kiva", "random_room"} <= set(rows)
    assert rows["random_room"]["procedural"] and rows["random_room"]["stages"] == [] and rows["random_room"]["assets"] > 200
    assert rows["room"]["stages"] and rows["room"]["assets"] >= 10


def test_desk_tops_are_finished_as_office_desks_light_and_near_neutral(cache):
    """Every work surface of the office and lab kinds gets one finish on all its top materials (its
    woods and textures, not its metal or rubber): a light grain texture whose tinted mean colour is
    a laminate's, so no desk is the red, blue or varnished wood the floors may be."""
    import colorsys

    from specsynth.model.colour import linear_to_srgb
    from specsynth.scenes import random_room as rr

    grain = [t for t in textures.available(cache) if t.name in rr.DESK_GRAIN]
    assert len(grain) == len(rr.DESK_GRAIN)
    finishes = np.array(rr.DESK_FINISHES)
    ids = [i for i in furniture.catalogue() if any(re.match(p, i.id) for p in rr.WORKTOPS.values())]
    assert len(ids) >= 10
    for k, item in enumerate(ids):
        tops = rr.top_materials(item, cache)
        assert not any(rr.NOT_TOP_WORDS.search(n) for n in tops)
        for seed in range(4):
            done = rr.finish_top(np.random.default_rng((k, seed)), item, cache, grain)
            assert set(done) == set(tops) and len({m.model_dump_json() for m in done.values()}) <= 1
            for m in list(done.values())[:1]:
                mean = linear_to_srgb(rr.mean_linear_colour(Path(m.texture)) * np.array(m.base_color))
                h, s, v = colorsys.rgb_to_hsv(*mean)
                # the drawn finish within the brightness draw (0.9-1.05 in linear light), or darker where no grain is light enough
                assert s <= 0.4 and np.abs(finishes / finishes.max(1, keepdims=True) - mean / mean.max()).max(1).min() < 0.05
    assert rr.top_materials(furniture.find("Blend Swap CC-0#lbDesk"), cache) == ["Desk"]
    room, credits = random_room(3, cache, kind="office_desk")
    desk = next(m for m in room.meshes if m.name.startswith("furniture_") and rr.is_worktop(furniture.find(m.source.furniture)))
    used = {Path(m.texture).name for m in desk.materials.values() if m.texture}
    assert used and used <= {Path(t.path).name for t in grain}
    assert {t.credit["asset"] for t in grain if Path(t.path).name in used} <= {c["asset"] for c in credits}


def test_offices_and_labs_are_in_office_colours_other_rooms_as_before(cache):
    """Offices and labs: white to pale grey walls, neutral floors or dark grey carpet, furniture in
    neutral woods, no rug; living rooms keep their rugs."""
    import colorsys

    from specsynth.model.colour import linear_to_srgb
    from specsynth.scenes import random_room as rr

    names = {Path(t.path).name: t for t in textures.available(cache)}
    rugs = 0
    for seed in range(12):
        for kind in rr.OFFICE_KINDS:
            room, _ = random_room(seed, cache, kind=kind)
            by = {m.name: m for m in room.meshes}
            assert "rug" not in by
            floor = names[Path(by["floor"].material.texture).name]
            assert floor.name in rr.OFFICE_FLOORS or by["floor"].material.base_color in rr.CARPETS
            wall = by["wall_south"].material
            assert names[Path(wall.texture).name].name in rr.OFFICE_WALLS and wall.base_color in rr.OFFICE_PAINTS
            for m in room.meshes:
                if m.name.startswith("furniture_"):
                    for mat in m.materials.values():
                        t = names.get(Path(mat.texture).name) if mat.texture else None
                        assert t is None or t.kind != "floor" or t.name in rr.OFFICE_FLOORS, (kind, t.name)
        rugs += any(m.name == "rug" for m in random_room(seed, cache, kind="living_room")[0].meshes)
    assert rugs >= 3
    for c in rr.CARPETS + rr.OFFICE_PAINTS:  # near grey as shown (sRGB)
        assert colorsys.rgb_to_hsv(*linear_to_srgb(np.array(c)))[1] <= 0.12

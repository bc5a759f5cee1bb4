"""Asset resolution on real files: the installed LM-O models, pybullet_data built-ins, generic meshes."""

from __future__ import annotations

import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import assume, example, given, settings
from hypothesis import strategies as st

from specsynth.assets import resolve as assets
from specsynth.assets.library.cache import cache_dir
from specsynth.assets.library.realsets import resolve_ref
from specsynth.assets.meshio import read_mesh
from specsynth.assets.resolve import AssetError
from specsynth.spec.models import Material, MeshObject, Objects

# The installed LM-O models (make install): looked up before any test points SPECSYNTH_CACHE elsewhere.
LMO = resolve_ref("dataset:lmo/models", cache_dir())
DATA = Path(__file__).parent / "data"


@pytest.fixture()
def cache(tmp_path, monkeypatch):
    c = tmp_path / "cache"
    monkeypatch.setenv("SPECSYNTH_CACHE", str(c))
    return c


def _resolve(objects, spec_dir, cache):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = assets.resolve_objects(objects, spec_dir, cache)
    return out, [str(w.message) for w in caught]


def _ascii_ply_vertices(path: Path) -> np.ndarray:
    """The vertex rows of an ASCII PLY, read with numpy alone (x y z nx ny nz r g b a)."""
    lines = path.read_text().splitlines()
    end = lines.index("end_header")
    n = int(next(ln.split()[2] for ln in lines[:end] if ln.startswith("element vertex")))
    return np.loadtxt(lines[end + 1 : end + 1 + n], dtype=np.float64)


def test_lmo_models_as_is(cache, tmp_path):
    """The LM-O models the install provides (BOP PLYs in mm with vertex colours, no
    models_info.json): metres, colours kept, box and diameter those of the file's own vertices
    (computed here with scipy) and, for the ape, BOP's published models_info numbers."""
    from scipy.spatial import ConvexHull
    from scipy.spatial.distance import pdist

    res, _ = _resolve(Objects(path=str(LMO)), tmp_path, cache)
    assert [a.obj_id for a in res] == [1, 5, 6, 8, 9, 10, 11, 12]
    for a in res:
        rows = _ascii_ply_vertices(LMO / f"obj_{a.obj_id:06d}.ply")
        xyz, rgb = rows[:, :3] / 1000.0, rows[:, 6:9]
        assert a.material.use_vertex_colors and a.material.texture is None
        assert a.bbox_min == pytest.approx(xyz.min(0), abs=1e-6)
        assert a.extents == pytest.approx(xyz.max(0) - xyz.min(0), abs=1e-6)
        assert a.diameter == pytest.approx(pdist(xyz[ConvexHull(xyz).vertices]).max(), abs=1e-6)
        mesh = read_mesh(a.mesh_path)
        assert len(mesh.vertices) >= len(xyz) and mesh.colors is not None
        assert mesh.vertices.min(0) == pytest.approx(xyz.min(0), abs=1e-5)
        assert mesh.colors[:, :3].astype(float).mean(0) == pytest.approx(rgb.mean(0), abs=2.0)  # 0-255
    ape = res[0]
    assert ape.diameter * 1000 == pytest.approx(102.099, abs=1e-3) and ape.bbox_min[0] * 1000 == pytest.approx(-37.9343, abs=1e-3)
    # ids subset; names; the second resolution is a cache hit
    res2, _ = _resolve(Objects(path=str(LMO), ids=[5]), tmp_path, cache)
    assert [(a.obj_id, a.name) for a in res2] == [(5, "obj_000005")]
    assert res2[0].mesh_key == res[1].mesh_key


def test_bop_folder_errors(cache, tmp_path):
    with pytest.raises(AssetError, match="BOP website.*never downloads"):
        assets.object_fingerprints(Objects(path="does/not/exist"), tmp_path)
    with pytest.raises(AssetError, match="NO_SUCH_VAR_XYZ"):
        assets.object_fingerprints(Objects(path="${NO_SUCH_VAR_XYZ}/models"), tmp_path)
    (tmp_path / "m").mkdir()
    with pytest.raises(AssetError, match="models_info.json"):
        assets.resolve_objects(Objects(path="m"), tmp_path, cache)
    (tmp_path / "m" / "models_info.json").write_text('{"1": {}}')
    with pytest.raises(AssetError, match="obj_000001"):
        assets.object_fingerprints(Objects(path="m"), tmp_path)


def test_mm_and_m_give_same_geometry(cache, tmp_path):
    mm = DATA / "cube_mm.ply"
    text = mm.read_text().splitlines()
    # Same cube written in metres.
    body = [" ".join([str(float(x) / 1000) for x in ln.split()[:3]] + ln.split()[3:]) if i < 8 else ln
            for i, ln in enumerate(text[text.index("end_header") + 1:])]
    m_file = tmp_path / "cube_m.ply"
    m_file.write_text("\n".join(text[: text.index("end_header") + 1] + body) + "\n")
    objs = Objects(meshes=[MeshObject(path=str(mm), unit="mm", name="a"), MeshObject(path="cube_m.ply", unit="m", name="b")])
    a, b = assets.resolve_objects(objs, tmp_path, cache)
    ma, mb = read_mesh(a.mesh_path), read_mesh(b.mesh_path)
    np.testing.assert_allclose(ma.vertices, mb.vertices, atol=1e-7)
    assert np.array_equal(ma.faces, mb.faces) and len(ma.faces) == 12  # quads triangulated
    assert a.diameter == pytest.approx(0.04 * np.sqrt(3), rel=1e-5)
    assert (a.obj_id, b.obj_id) == (1, 2)
    assert ma.colors is not None and a.material.use_vertex_colors


def test_bad_meshes_name_the_file(cache, tmp_path):
    (tmp_path / "empty.obj").write_bytes(b"")
    (tmp_path / "garbage.stl").write_bytes(b"\x00\x01 not a mesh" * 3)
    nan = (DATA / "cube_mm.ply").read_text().replace("-20 -20 -20 200", "nan -20 -20 200", 1)
    (tmp_path / "nan.ply").write_text(nan)
    cases = {
        "missing.ply": ("mm", "missing.ply"),
        "empty.obj": ("m", "empty.obj"),
        "garbage.stl": ("m", "garbage.stl"),
        "nan.ply": ("mm", "NaN"),
        str(DATA / "truncated.ply"): ("mm", "truncated.ply"),
    }
    for path, (unit, needle) in cases.items():
        with pytest.raises(AssetError, match=needle.replace(".", r"\.")) as e:
            assets.resolve_objects(Objects(meshes=[MeshObject(path=path, unit=unit)]), tmp_path, cache)
        assert Path(path).name in str(e.value)


def test_absurd_units(cache, tmp_path):
    # A 40 mm cube declared in metres is 69 m across: absurd; a mm cube of 0.04 units is 69 um.
    with pytest.raises(AssetError, match="check 'unit'"):
        assets.resolve_objects(Objects(meshes=[MeshObject(path=str(DATA / "cube_mm.ply"), unit="m")]), tmp_path, cache)
    tiny = (DATA / "cube_mm.ply").read_text().replace("20", "0.02")
    (tmp_path / "tiny.ply").write_text(tiny)
    with pytest.raises(AssetError, match="tiny.ply.*check 'unit'"):
        assets.resolve_objects(Objects(meshes=[MeshObject(path="tiny.ply", unit="mm")]), tmp_path, cache)


def test_corrupt_texture_is_an_error_missing_is_a_warning(cache, tmp_path):
    text = (DATA / "cube_mm.ply").read_text().replace("comment tiny", "comment TextureFile tex.png\ncomment tiny")
    (tmp_path / "t.ply").write_text(text)
    _, warns = _resolve(Objects(meshes=[MeshObject(path="t.ply", unit="mm")]), tmp_path, cache)
    assert any("tex.png" in w for w in warns)
    (tmp_path / "tex.png").write_bytes(b"\x89PNG\r\n\x1a\n garbage")
    with pytest.raises(AssetError, match="tex.png.*unreadable"):
        assets.resolve_objects(Objects(meshes=[MeshObject(path="t.ply", unit="mm")]), tmp_path, cache)


def test_builtins_metric_and_upright(cache, tmp_path):
    objs = Objects(path=str(LMO), builtin=["duck", "teddy", "mug", "jenga"])
    res = {a.name: a for a in _resolve(objs, tmp_path, cache)[0]}
    duck, teddy, mug, jenga = (res[n] for n in ("duck", "teddy", "mug", "jenga"))
    assert 0.05 <= duck.diameter <= 0.2 and 0.03 <= teddy.diameter <= 0.3
    assert 0.05 <= mug.diameter <= 0.2
    assert jenga.extents == pytest.approx((0.15, 0.05, 0.03), abs=1e-4)
    # duck.obj is Y-up: made canonical (+Z up), it is longer than tall.
    assert duck.extents[2] < duck.extents[0]
    for a in (duck, teddy, mug, jenga):  # BOP's model origin: the centre of the 3D bounding box
        assert np.asarray(a.bbox_min) + np.asarray(a.extents) / 2 == pytest.approx((0, 0, 0), abs=1e-6)
    import pybullet_data

    src_png = Path(pybullet_data.getDataPath()) / "duckCM.png"
    assert Path(duck.material.texture).read_bytes() == src_png.read_bytes()  # a copy in the cache
    assert Path(duck.material.texture).is_relative_to(cache) and read_mesh(duck.mesh_path).uv is not None
    # Built-ins follow the BOP ids in list order.
    first = max(a.obj_id for a in res.values() if a.name not in ("duck", "teddy", "mug", "jenga"))
    assert [duck.obj_id, teddy.obj_id, mug.obj_id, jenga.obj_id] == list(range(first + 1, first + 5))
    assert "random_urdfs/000" in assets.builtin_objects() and "duck" in assets.builtin_objects()
    with pytest.raises(AssetError, match="did you mean duck"):
        assets.object_fingerprints(Objects(builtin=["duk"]), tmp_path)


def test_material_overrides(cache, tmp_path):
    objs = Objects(
        builtin=["duck", "mug"],
        materials={"default": Material(roughness=0.9), "duck": Material(color=(0.1, 0.2, 0.3), metallic=1.0)},
    )
    duck, mug = assets.resolve_objects(objs, tmp_path, cache)
    assert duck.material.texture is None and duck.material.base_color == (0.1, 0.2, 0.3)
    assert not duck.material.use_vertex_colors and duck.material.metallic == 1.0
    assert mug.material.roughness == 0.9


def test_fingerprints_stable_and_content_sensitive(tmp_path):
    f = tmp_path / "c.ply"
    shutil.copy(DATA / "cube_mm.ply", f)
    objs = Objects(meshes=[MeshObject(path="c.ply", unit="mm", name="c")], builtin=["duck"])
    a = assets.object_fingerprints(objs, tmp_path)
    assert a == assets.object_fingerprints(objs, tmp_path) and set(a) == {"c", "duck"}
    f.write_text(f.read_text().replace("200 30 30", "201 30 30", 1))
    os.utime(f, ns=(f.stat().st_atime_ns, f.stat().st_mtime_ns + 10**9))
    b = assets.object_fingerprints(objs, tmp_path)
    assert b["c"] != a["c"] and b["duck"] == a["duck"]
    objs_cm = Objects(meshes=[MeshObject(path="c.ply", unit="cm", name="c")])
    assert assets.object_fingerprints(objs_cm, tmp_path)["c"] != b["c"]


def test_hdris():
    pytest.importorskip("bpy")  # the HDRIs ship with the bpy wheel: with it installed they must be found
    names = assets.builtin_hdris()
    assert len(names) == 8 and "interior" in names
    assert assets.hdri_path("interior").suffix == ".exr"
    with pytest.raises(AssetError, match="unknown"):
        assets.hdri_path("nope")


def test_cached_asset_never_points_into_another_folder(cache, tmp_path):
    """Two folders with the same OBJ + texture bytes share one cache entry; changing (or deleting)
    the first folder's texture afterwards must not change what the second build renders."""
    from PIL import Image

    def folder(name):
        d = tmp_path / name
        d.mkdir()
        (d / "box.obj").write_text("mtllib box.mtl\nv 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\n"
                                   "vt 0 0\nvt 1 0\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3\nf 1/1 3/3 4/2\nf 1/1 4/2 2/2\nf 2/2 4/2 3/3\n")
        (d / "box.mtl").write_text("newmtl m\nmap_Kd tex.png\n")
        Image.new("RGB", (4, 4), (200, 10, 10)).save(d / "tex.png")
        return d

    a, b = folder("a"), folder("b")
    (obj_a,) = assets.resolve_objects(Objects(meshes=[MeshObject(path=str(a / "box.obj"), unit="m")]), tmp_path, cache)
    Image.new("RGB", (4, 4), (10, 200, 10)).save(a / "tex.png")  # the user edits folder a later
    (obj_b,) = assets.resolve_objects(Objects(meshes=[MeshObject(path=str(b / "box.obj"), unit="m")]), tmp_path, cache)
    assert obj_b.material.texture is not None and not Path(obj_b.material.texture).is_relative_to(a)
    assert Path(obj_b.material.texture).read_bytes() == (b / "tex.png").read_bytes()
    (a / "tex.png").unlink()
    assert Path(obj_a.material.texture).is_file()  # the first build's copy survives its source


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 31), st.floats(0.0, 0.6))
def test_unusable_normals_are_replaced_by_their_faces_normal(seed, broken):
    """A normal of zero length or NaN (library furniture has some) becomes the area-weighted normal
    of its faces; every other normal is kept as it was; faces end up wound the way they point."""
    from specsynth.assets.meshio import MeshData

    rng = np.random.default_rng(seed)
    z = rng.uniform(-0.2, 0.2, 9)
    xs, ys = np.meshgrid(np.arange(3.0), np.arange(3.0))
    v = np.stack([xs.ravel(), ys.ravel(), z], axis=1)
    f = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6], [4, 5, 8], [4, 8, 7]])
    n = rng.normal(size=(9, 3)) * 0.3  # roughly up, as a height field's normals are: never below the
    n[:, 2] = 1.0  # horizon (one that is would be a corner pointing away from its faces, another rule)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    bad = rng.random(9) < broken
    n[bad] = np.where(rng.random((bad.sum(), 1)) < 0.5, 0.0, np.nan)
    fixed = MeshData(vertices=v.astype(np.float32), faces=f, normals=n.astype(np.float32)).with_usable_normals().normals[:9]
    assert np.isfinite(fixed).all() and np.allclose(np.linalg.norm(fixed, axis=1), 1.0, atol=1e-5)
    assert np.array_equal(fixed[~bad], n[~bad].astype(np.float32))
    assert (fixed[bad][:, 2] > 0).all()  # a height field wound counter-clockwise faces +z
    # Turned upside down, the same faces are re-wound to agree with the (downward) normals.
    down = MeshData(vertices=v.astype(np.float32), faces=f, normals=np.tile([0.0, 0.0, -1.0], (9, 1)).astype(np.float32))
    g = down.with_usable_normals().faces
    vv = v[g]
    assert (np.cross(vv[:, 1] - vv[:, 0], vv[:, 2] - vv[:, 0])[:, 2] < 0).all()


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 31), st.floats(0.05, 0.9))
def test_faces_whose_corners_point_elsewhere_are_drawn_flat(seed, flipped):
    """A corner normal pointing away from its face (a desk top's slivers sharing a vertex with its
    underside) gives that face its own corners with its flat normal: afterwards every face agrees
    with its corners, the triangles, their UVs and colours are where they were, and faces that
    agreed keep their shared vertices and smooth normals."""
    from specsynth.assets.meshio import DISAGREE, MeshData

    rng = np.random.default_rng(seed)
    xs, ys = np.meshgrid(np.arange(4.0), np.arange(4.0))
    v = np.stack([xs.ravel(), ys.ravel(), rng.uniform(-0.1, 0.1, 16)], axis=1).astype(np.float32)
    quads = [(r * 4 + c, r * 4 + c + 1, r * 4 + c + 5, r * 4 + c + 4) for r in range(3) for c in range(3)]
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    n = np.tile([0.0, 0.0, 1.0], (16, 1))
    n[rng.random(16) < flipped] = [0.0, 0.0, -1.0]
    uv = rng.random((16, 2)).astype(np.float32)
    colors = rng.integers(0, 256, (16, 4)).astype(np.uint8)
    mesh = MeshData(vertices=v, faces=f, normals=n.astype(np.float32), uv=uv, colors=colors)
    out = mesh.with_usable_normals()
    fv = out.vertices[out.faces].astype(np.float64)
    unit = np.cross(fv[:, 1] - fv[:, 0], fv[:, 2] - fv[:, 0])
    unit /= np.linalg.norm(unit, axis=1, keepdims=True)
    assert (np.einsum("fkj,fj->fk", out.normals[out.faces], unit) >= DISAGREE - 1e-6).all()
    # The same triangles (as sets of corners, winding aside), with the same UVs and colours.
    def corners(m):
        return sorted(tuple(sorted(map(tuple, np.concatenate([m.vertices[t], m.uv[t], m.colors[t]], axis=1).tolist())))
                      for t in m.faces)
    assert corners(out) == corners(mesh)
    agreed = (np.einsum("fkj,fj->fk", mesh.normals[mesh.faces], np.sign(mesh.normals[mesh.faces].sum(1)[:, 2:3])
                        * [[0.0, 0.0, 1.0]]).min(axis=1) >= DISAGREE)
    assert (out.faces[agreed] < 16).all()


def _uv_grid(rng):
    """A 4 x 4 grid of vertices in 18 triangles with texture coordinates within a few repeats."""
    xs, ys = np.meshgrid(np.arange(4.0), np.arange(4.0))
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(16)], axis=1).astype(np.float32)
    quads = [(r * 4 + c, r * 4 + c + 1, r * 4 + c + 5, r * 4 + c + 4) for r in range(3) for c in range(3)]
    f = np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])
    return v, f, (rng.random((16, 2)) * 8 - 4).astype(np.float32)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2 ** 31), st.floats(0.0, 0.6))
def test_broken_texture_coordinates_take_their_neighbours(seed, broken):
    """A texture coordinate that is not finite or lies beyond UV_LIMIT repeats (a Sweet Home 3D
    table had four at u = 3.4e9, which Mitsuba drew as 1e14-bright fireflies) is replaced, u and v
    each on its own, by the mean of the valid ones it shares faces with; valid ones are kept bit
    for bit, the input is left as it was, and a mesh without broken ones is returned as it is."""
    from specsynth.assets.meshio import UV_LIMIT, MeshData

    rng = np.random.default_rng(seed)
    v, f, uv = _uv_grid(rng)
    bad = rng.random((16, 2)) < broken
    uv[bad] = rng.choice([np.nan, np.inf, -np.inf, 3.4e9, -2 * UV_LIMIT], int(bad.sum()))
    before = uv.copy()
    mesh = MeshData(vertices=v, faces=f, uv=uv)
    out = mesh.with_usable_uv()
    assert np.array_equal(uv, before, equal_nan=True)
    if not bad.any():
        assert out is mesh
        return
    assert np.isfinite(out.uv).all() and (np.abs(out.uv) <= 4).all()
    assert np.array_equal(out.uv[~bad], uv[~bad])
    for i, c in zip(*np.nonzero(bad)):
        # the valid neighbours of the first pass, each counted once per face it shares with the vertex
        weights = {j: sum(1 for face in f if i in face and j in face) for face in f if i in face for j in face
                   if j != i and not bad[j, c]}
        if weights:
            want = sum(w * float(uv[j, c]) for j, w in weights.items()) / sum(weights.values())
            assert out.uv[i, c] == pytest.approx(want, abs=1e-5)


def test_a_face_of_broken_texture_coordinates_takes_its_neighbours():
    """Every corner of a face broken: each takes its valid neighbours' mean, then the rest take
    theirs, so the face keeps an area in texture space instead of collapsing to (0, 0)."""
    from specsynth.assets.meshio import MeshData

    v, f, uv = _uv_grid(np.random.default_rng(3))
    uv[:, 0] = np.arange(16) % 4  # u runs 0..3 along each row: the grid's own layout
    uv[[0, 1, 4, 5], 0] = 3.4e9  # the corner quad's four corners
    out = MeshData(vertices=v, faces=f, uv=uv).with_usable_uv().uv
    assert np.isfinite(out).all() and (out[[1, 4, 5], 0] > 0).all()
    # corner 0 reaches no valid u in the first pass: it takes its faces' (0, 1, 5) and (0, 5, 4) repaired ones
    assert out[0, 0] == pytest.approx((out[1, 0] + 2 * out[5, 0] + out[4, 0]) / 4, abs=1e-5)
    assert np.array_equal(out[:, 1], uv[:, 1])  # v was valid everywhere and is kept


def _box(lo, hi):
    """A closed box, faces wound outwards, as (vertices, faces)."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    v = np.array([[x, y, z] for z in (z0, z1) for y in (y0, y1) for x in (x0, x1)], np.float64)
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return v, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))])


def _floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_subnormal=False)


@settings(max_examples=100, deadline=None)
@given(st.tuples(*[_floats(-1, 0)] * 3), st.tuples(*[_floats(0.05, 1.0)] * 3), st.tuples(*[_floats(0.3, 0.7)] * 2))
def test_back_to_back_faces_keep_one_side(corner, size, at):
    """Faces lying in a surface of the other orientation (the desk top's downward slivers) give
    way; a closed box keeps every face; a zero-thickness sheet keeps exactly one side."""
    from specsynth.assets.meshio import MeshData
    from specsynth.assets.repair import drop_overlapping

    lo = np.asarray(corner)
    hi = lo + np.asarray(size)
    v, f = _box(lo, hi)
    box = MeshData(vertices=v.astype(np.float32), faces=f)
    assert drop_overlapping(box) is box
    # A downward triangle inside the top face (z = hi), like the desk's: it goes, the box stays.
    c = lo[:2] + np.asarray(at) * (hi[:2] - lo[:2])
    r = 0.2 * min(hi[0] - lo[0], hi[1] - lo[1])
    tri = np.array([[c[0], c[1], hi[2]], [c[0] + r, c[1], hi[2]], [c[0], c[1] - r, hi[2]]])  # clockwise from above
    mesh = MeshData(vertices=np.concatenate([v, tri]).astype(np.float32), faces=np.concatenate([f, [[8, 9, 10]]]))
    assert np.array_equal(drop_overlapping(mesh).faces, f)
    # A sheet drawn from both sides: one side stays, all of it.
    sheet = MeshData(vertices=v[:4].astype(np.float32), faces=np.array([[0, 2, 3], [0, 3, 1], [0, 3, 2], [0, 1, 3]]))
    kept = sheet.vertices[drop_overlapping(sheet).faces].astype(np.float64)
    facing = np.sign(np.cross(kept[:, 1] - kept[:, 0], kept[:, 2] - kept[:, 0])[:, 2])
    assert len(kept) == 2 and facing[0] == facing[1]


_corner = st.tuples(*[_floats(-1, 1)] * 3)
_face = st.lists(st.integers(0, 11), min_size=3, max_size=3, unique=True)


@settings(max_examples=100, deadline=None)
@given(st.lists(_corner, min_size=12, max_size=12), st.lists(_face, min_size=1, max_size=10),
       st.lists(_corner, min_size=12, max_size=12), st.lists(st.tuples(*[st.integers(0, 255)] * 4), min_size=12, max_size=12))
def test_box_uvs_project_each_face_along_its_axis_in_metres(corners, faces, normals, colours):
    """A mesh without UVs gets them by box projection (a texture given to it then shows, as with
    Blender's generated coordinates): each corner's UV is its position on the two axes other than
    the one its face's normal is closest to; the triangles, normals and colours are unchanged."""
    from specsynth.assets.meshfiles.primitives import with_box_uvs
    from specsynth.assets.meshio import MeshData

    v = np.asarray(corners, np.float32)
    f = np.asarray(faces, np.int32)
    n = np.asarray(normals, np.float32)
    colors = np.asarray(colours, np.uint8)
    out = with_box_uvs(MeshData(vertices=v, faces=f, normals=n, colors=colors))
    assert with_box_uvs(out) is out
    tri = out.vertices[out.faces].astype(np.float64)
    assert np.allclose(tri, v[f]) and np.array_equal(out.normals[out.faces], n[f])
    assert np.array_equal(out.colors[out.faces], colors[f])
    axis = np.argmax(np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    expected = np.take_along_axis(tri, np.repeat(keep[:, None, :], 3, axis=1), axis=2)
    assert np.allclose(out.uv[out.faces], expected, atol=1e-6)


def _overlap_area(p: np.ndarray, q: np.ndarray) -> float:
    """Area of the intersection of two 2D triangles, by clipping one against the other's edges
    (Sutherland-Hodgman): an oracle that shares nothing with repair's separating-axis test."""
    turn = np.cross(q[1] - q[0], q[2] - q[0])
    if turn == 0 or np.cross(p[1] - p[0], p[2] - p[0]) == 0:
        return 0.0  # a degenerate triangle covers nothing
    if turn < 0:
        q = q[::-1]
    poly = [tuple(x) for x in p]
    for k in range(3):
        a, b = q[k], q[(k + 1) % 3]
        side = [float(np.cross(b - a, np.asarray(x) - a)) for x in poly]
        out = []
        for i, x in enumerate(poly):
            y, sx, sy = poly[(i + 1) % len(poly)], side[i], side[(i + 1) % len(poly)]
            if sx >= 0:
                out.append(x)
            if (sx >= 0) != (sy >= 0):
                w = sx / (sx - sy)
                out.append(tuple(np.asarray(x) + w * (np.asarray(y) - np.asarray(x))))
        poly = out
        if len(poly) < 3:
            return 0.0
    x, y = np.asarray(poly).T
    return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


_coord = st.floats(0, 2, allow_nan=False, allow_subnormal=False)
_offset = st.floats(-0.3, 0.3, allow_nan=False, allow_subnormal=False)
_triangle = st.tuples(_coord, _coord, *[_offset] * 6)


@settings(max_examples=200, deadline=None)
@given(st.lists(_triangle, min_size=2, max_size=80))
def test_overlapping_coplanar_faces_keep_a_largest_first_cover(drawn):
    """In a plane crowded with triangles (some planes small, some over the all-pairs size), the kept
    faces never overlap each other, and every dropped face overlaps a kept face at least as large;
    overlap measured as the area two triangles share, clipped polygon by polygon."""
    from specsynth.assets.meshio import MeshData
    from specsynth.assets.repair import drop_overlapping

    d = np.asarray(drawn, np.float64)
    n = len(d)
    tri2 = d[:, None, :2] + d[:, 2:].reshape(n, 3, 2)
    v = np.concatenate([tri2.reshape(-1, 2), np.full((3 * n, 1), 0.5)], axis=1).astype(np.float32)
    f = np.arange(3 * n).reshape(n, 3)
    out = drop_overlapping(MeshData(vertices=v, faces=f))
    t = v[:, :2].astype(np.float64)[f]
    area = 0.5 * np.abs(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]))
    kept = sorted({int(x) // 3 for x in out.faces[:, 0]})
    dropped = sorted(set(range(n)) - set(kept))
    # Faces touching along an edge, or overlapping by less than repair's 0.1 mm, share at most a
    # sliver: 0.1 mm times the longest edge (0.85 m here).
    sliver = 1e-4 * 0.85 * 2
    for i, a in enumerate(kept):
        for b in kept[i + 1 :]:
            assert _overlap_area(t[a], t[b]) <= sliver, (a, b)
    for x in dropped:
        assert area[x] > 0 and any(area[k] >= area[x] - 1e-12 and _overlap_area(t[x], t[k]) > 0 for k in kept), x


def _tilted(points2: np.ndarray, normal: np.ndarray, origin: np.ndarray) -> np.ndarray:
    n = normal / np.linalg.norm(normal)
    u = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    return origin + points2[:, :1] * u + points2[:, 1:] * np.cross(n, u)


_unit = st.floats(-1, 1, allow_nan=False, allow_subnormal=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(_coord, _coord), min_size=4, max_size=60, unique=True),
       st.tuples(_unit, _unit, _unit).filter(lambda n: np.linalg.norm(n) > 0.1),
       st.tuples(_unit, _unit, _unit))
@example(points=[(1.75, 0.599609375), (1.3125, 0.682941567421811), (0.90625, 0.3875922532184176),
                 (0.31356057193341785, 0.333984375)], normal=(0.0, 0.0, 1.0), origin=(0.0, 0.0, 0.0))
def test_a_proper_triangulation_in_any_plane_is_untouched(points, normal, origin):
    """A proper triangulation (no two faces overlap: Delaunay) of points in a plane of any tilt, and
    the closed convex hull of the same points lifted off the plane, keep every face."""
    from scipy.spatial import ConvexHull, Delaunay, QhullError

    from specsynth.assets.meshio import MeshData
    from specsynth.assets.repair import drop_overlapping

    p2 = np.asarray(points, np.float64)
    try:
        faces = Delaunay(p2).simplices
    except QhullError:  # all points on one line: no triangulation to check
        assume(False)
    v = _tilted(p2, np.asarray(normal), np.asarray(origin))
    faces = _not_slivers(v, faces)
    assume(len(faces) >= 2)
    sheet = MeshData(vertices=v.astype(np.float32), faces=faces.astype(np.int32))
    assert drop_overlapping(sheet) is sheet
    lifted = v + np.sin(7.0 * p2[:, :1] + 3.0 * p2[:, 1:]) * np.asarray(normal) / np.linalg.norm(normal)
    try:
        hull = _not_slivers(lifted, ConvexHull(lifted).simplices)
    except QhullError:
        assume(False)
    # A hull flatter than repair's 0.1 mm tolerance is a sheet lying on itself, whose overlapping
    # faces repair rightly drops (four points within 0.05 mm of one plane made one): 2 mm, as slivers.
    assume(_thickness(lifted, hull) >= 2e-3)
    closed = MeshData(vertices=lifted.astype(np.float32), faces=hull.astype(np.int32))
    assert drop_overlapping(closed) is closed


def _thickness(v: np.ndarray, faces: np.ndarray) -> float:
    """The least, over the faces of a convex hull, of the farthest vertex from the face's plane."""
    t = v[faces]
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)
    return float(np.abs(np.einsum("fj,vj->fv", n, v) - np.einsum("fj,fj->f", n, t[:, 0])[:, None]).max(1).min()) if len(faces) else 0.0


def _not_slivers(v: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """The faces at least 2 mm high on their longest edge: a sliver thinner than repair's 0.1 mm
    tolerance (points a micrometre off a line) is below what "overlap" can mean; leaving faces
    out of a proper triangulation leaves one."""
    t = v[faces]
    cross = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    longest = np.linalg.norm(t - np.roll(t, 1, axis=1), axis=2).max(1)
    return faces[cross / np.maximum(longest, 1e-30) >= 2e-3]


def test_a_colour_gain_multiplies_the_objects_colours(tmp_path):
    """objects.materials.<id>.color_gain scales the base colour the vertex colours are multiplied by."""
    from specsynth.assets.resolve import resolve_objects
    from specsynth.spec.models import Objects

    plain = {a.obj_id: a for a in resolve_objects(Objects(path="dataset:lmo/models"), tmp_path)}
    gained = {a.obj_id: a for a in resolve_objects(Objects(path="dataset:lmo/models", materials={
        "9": {"color_gain": [2.0, 1.5, 0.5]}}), tmp_path)}
    assert plain[9].material.use_vertex_colors and gained[9].material.use_vertex_colors
    np.testing.assert_allclose(gained[9].material.base_color, np.array(plain[9].material.base_color) * [2.0, 1.5, 0.5])
    assert gained[1].material == plain[1].material
    with pytest.raises(ValueError, match="colour gain"):
        Objects(path="dataset:lmo/models", materials={"9": {"color_gain": [5.0, 1.0, 1.0]}})


def test_a_mesh_trimesh_cannot_parse_names_its_format_and_quotes_none_of_it(tmp_path):
    from specsynth.assets.meshfiles.part import MeshFileError
    from specsynth.assets.meshfiles.single import read_single

    bad = tmp_path / "part.off"
    bad.write_text("OFF\n3 1 0\nSECRET-COORDINATE 0 0\n")
    with pytest.raises(MeshFileError) as e:
        read_single(bad)
    assert "part.off: not a readable OFF file (trimesh raised ValueError)" in str(e.value)
    assert "SECRET" not in str(e.value)

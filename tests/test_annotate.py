"""Annotation engine against hand-derived BOP gt_info numbers (real pyrender renders over EGL).

Test scenes use the camera frame as world frame (R = I, t = 0) and thin axis-aligned boxes
("cards") whose front faces project to pixel rectangles with edges at n + 0.3 and m + 0.7, so a
card covers pixel centres n+1 .. m exactly; a half-pixel error in the projection would add a
row or column. The 2 mm thickness moves silhouette edges by < 0.1 px.
"""

import numpy as np
import pytest
import trimesh

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import CameraIR, MeshInstance, RenderScene, as_tuple
from specsynth.views.cameras import camera_pose, project

W, H = 64, 48
FX = FY = 100.0
CX, CY = 32.0, 24.0
K = np.array([[FX, 0, CX], [0, FY, CY], [0, 0, 1]])
THICK = 0.002
DELTA = 0.005


@pytest.fixture(scope="module")
def annotator():
    from specsynth.annotate.engine import Annotator

    ann = Annotator(W, H)  # the engine must start: a failure here fails every test that uses it
    yield ann
    ann.close()


def camera(K=K, R=np.eye(3), t=np.zeros(3), near=0.01, far=10.0):
    return CameraIR(K=as_tuple(K), width=W, height=H, R_w2c=as_tuple(R), t_w2c=as_tuple(t), near=near, far=far)


def write_trimesh(path, mesh: trimesh.Trimesh) -> str:
    write_mesh(path, MeshData(vertices=np.asarray(mesh.vertices, np.float32), faces=np.asarray(mesh.faces, np.int32)))
    return str(path)


def pose(translation, R=np.eye(3)):
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = translation
    return as_tuple(T)


def card(tmp_path, name, u0, u1, v0, v1, z, obj_id=None, inst=None):
    """Box whose front face, at depth z, projects to [u0, u1] x [v0, v1] (pixel-centre coords)."""
    x0, x1 = (u0 - CX) / FX * z, (u1 - CX) / FX * z
    y0, y1 = (v0 - CY) / FY * z, (v1 - CY) / FY * z
    path = write_trimesh(tmp_path / f"{name}.ply", trimesh.creation.box(extents=[x1 - x0, y1 - y0, THICK]))
    return MeshInstance(
        name=name, mesh_path=path, mesh_key=f"key-{name}",
        pose=pose([(x0 + x1) / 2, (y0 + y1) / 2, z + THICK / 2]), obj_id=obj_id, inst=inst,
    )


def rect(c0, c1, r0, r1):
    m = np.zeros((H, W), bool)
    m[max(r0, 0) : r1 + 1, max(c0, 0) : c1 + 1] = True
    return m


@pytest.fixture
def analytic_scene(tmp_path):
    plane = card(tmp_path, "plane", -200, 300, -200, 300, 2.0)  # covers the view, scene geometry
    A = card(tmp_path, "A", 10.3, 30.7, 8.3, 28.7, 1.0, obj_id=1, inst=0)  # cols 11..30, rows 9..28
    B = card(tmp_path, "B", 20.3, 40.7, 4.3, 40.7, 0.8, obj_id=2, inst=1)  # cols 21..40, rows 5..40
    C = card(tmp_path, "C", 50.3, 80.7, 30.3, 40.7, 1.5, obj_id=3, inst=2)  # cols 51..80 (right border)
    D = card(tmp_path, "D", 40.3, 50.7, 5.3, 10.7, 2.5, obj_id=4, inst=3)  # behind the plane
    E = card(tmp_path, "E", -10.7, 5.7, -5.7, 3.7, 1.2, obj_id=1, inst=4)  # cols -10..5, rows -5..3
    # mesh order differs from gt order on purpose
    return RenderScene(meshes=(plane, C, A, E, B, D))


# hand-derived: (px_all, px_valid, px_visib, bbox_obj, bbox_visib)
EXPECTED_SCENE = {
    0: (400, 400, 200, [11, 9, 19, 19], [11, 9, 9, 19]),  # right half hidden by B
    1: (720, 720, 720, [21, 5, 19, 35], [21, 5, 19, 35]),
    2: (300, 130, 130, [51, 31, 29, 9], [51, 31, 12, 9]),  # 13 of 30 columns inside the image
    3: (50, 50, 0, [-1, -1, -1, -1], [-1, -1, -1, -1]),  # BOP leaves bbox_obj empty too
    4: (144, 24, 24, [-10, -5, 15, 8], [0, 0, 5, 3]),
}


def check(gt, expected):
    px_all, px_valid, px_visib, bbox_obj, bbox_visib = expected
    assert (gt.px_count_all, gt.px_count_valid, gt.px_count_visib) == (px_all, px_valid, px_visib)
    assert gt.bbox_obj == bbox_obj and gt.bbox_visib == bbox_visib
    assert gt.visib_fract == (px_visib / px_all if px_all else 0.0)


def test_analytic_gt_info(annotator, analytic_scene):
    annotator.load(analytic_scene)
    ann = annotator.annotate(camera(), DELTA)
    assert [g.inst for g in ann.instances] == [0, 1, 2, 3, 4]
    assert [g.obj_id for g in ann.instances] == [1, 2, 3, 4, 1]
    for gt in ann.instances:
        check(gt, EXPECTED_SCENE[gt.inst])
    # masks: amodal within the image, and visible parts
    np.testing.assert_array_equal(ann.masks[0], rect(11, 30, 9, 28))
    np.testing.assert_array_equal(ann.masks_visib[0], rect(11, 20, 9, 28))
    np.testing.assert_array_equal(ann.masks[2], rect(51, 63, 31, 40))
    np.testing.assert_array_equal(ann.masks[3], rect(41, 50, 6, 10))
    assert not ann.masks_visib[3].any()
    np.testing.assert_array_equal(ann.masks[4], rect(0, 5, 0, 3))
    for m, mv in zip(ann.masks, ann.masks_visib):
        assert m.dtype == bool and m.shape == (H, W) and not (mv & ~m).any()
    # depth: z of the nearest surface, metres (24-bit depth buffer: ~z^2/near * 6e-8)
    assert ann.depth.dtype == np.float32 and ann.depth.shape == (H, W)
    np.testing.assert_allclose(ann.depth[20, 15], 1.0, rtol=1e-4)  # A
    np.testing.assert_allclose(ann.depth[20, 25], 0.8, rtol=1e-4)  # B in front of A
    np.testing.assert_allclose(ann.depth[45, 5], 2.0, rtol=1e-4)  # plane
    # poses in metres, camera = world here
    A = analytic_scene.meshes[2]
    np.testing.assert_allclose(ann.instances[0].R_m2c, np.eye(3))
    np.testing.assert_allclose(ann.instances[0].t_m2c, A.matrix[:3, 3])


def test_visib_fract_precheck_matches(annotator, analytic_scene):
    annotator.load(analytic_scene)
    for inst, (px_all, _, px_visib, _, _) in EXPECTED_SCENE.items():
        assert annotator.visib_fract(camera(), inst, DELTA) == px_visib / px_all
    with pytest.raises(KeyError):
        annotator.visib_fract(camera(), 99, DELTA)


def test_occluders_objects_ignores_scene_geometry(annotator, analytic_scene):
    annotator.load(analytic_scene)
    ann = annotator.annotate(camera(), DELTA, occluders="objects")
    gts = {g.inst: g for g in ann.instances}
    check(gts[3], (50, 50, 50, [41, 6, 9, 4], [41, 6, 9, 4]))  # no plane: D is fully visible
    check(gts[0], EXPECTED_SCENE[0])  # B is an object, it still hides A
    check(gts[2], EXPECTED_SCENE[2])
    assert ann.depth[45, 5] == 0.0  # the plane is not in the depth either
    np.testing.assert_allclose(ann.depth[8, 45], 2.5, rtol=1e-4)


def test_delta_tolerance(annotator, analytic_scene):
    # D is ~0.5 m behind the plane: visible once the tolerance exceeds the gap
    annotator.load(analytic_scene)
    assert annotator.visib_fract(camera(), 3, 0.45) == 0.0
    assert annotator.visib_fract(camera(), 3, 0.6) == 1.0


def test_camera_pose_moves_everything(annotator, analytic_scene):
    """Same scene seen by a camera moved 0.1 m along world x: the image shifts by 10 px at z=1."""
    annotator.load(analytic_scene)
    ann = annotator.annotate(camera(t=np.array([0.1, 0.0, 0.0])), DELTA)
    # x_c = x_w + 0.1: A (z = 1) moves right by exactly 10 px
    np.testing.assert_array_equal(ann.masks[0], rect(21, 40, 9, 28))
    np.testing.assert_allclose(ann.instances[0].t_m2c[0], analytic_scene.meshes[2].matrix[0, 3] + 0.1)


def test_vertices_project_into_masks_and_pixel_centres(annotator, tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.05)
    box = trimesh.creation.box(extents=[0.06, 0.03, 0.04])
    s_path = write_trimesh(tmp_path / "sphere.ply", sphere)
    b_path = write_trimesh(tmp_path / "box.ply", box)
    # an off-integer principal point: a half-pixel convention error shifts the mask by 0.5 px
    K2 = np.array([[60.0, 0, 31.3], [0, 61.0, 23.8], [0, 0, 1]])
    R_box, _ = camera_pose((0, 0, 0), 33, 21, 1, 17)
    scene = RenderScene(
        meshes=(
            MeshInstance("sphere", s_path, "k-sphere", pose([0, 0, 0.6]), obj_id=1, inst=0),
            MeshInstance("box", b_path, "k-box", pose([0.09, -0.05, 0.5], R_box), obj_id=2, inst=1),
        )
    )
    annotator.load(scene)
    cam = camera(K=K2)
    ann = annotator.annotate(cam, DELTA)
    for gt, mesh, m, mv in zip(ann.instances, (sphere, box), ann.masks, ann.masks_visib):
        assert gt.visib_fract == 1.0 and (m == mv).all()  # nothing occludes them
        uv = project(K2, gt.R_m2c, gt.t_m2c, mesh.vertices)
        px = np.round(uv).astype(int)
        grown = m.copy()  # vertices lie on the silhouette: allow the neighbouring pixel
        grown[1:] |= m[:-1]
        grown[:-1] |= m[1:]
        grown[:, 1:] |= grown[:, :-1].copy()
        grown[:, :-1] |= grown[:, 1:].copy()
        assert grown[px[:, 1], px[:, 0]].all()
        # interior points (centroid of the visible faces towards the camera) hit mask pixels
        centre = project(K2, gt.R_m2c, gt.t_m2c, [mesh.vertices.mean(0)])[0]
        assert m[int(round(centre[1])), int(round(centre[0]))]
    # sphere on the optical axis: a disc centred on the principal point
    ys, xs = np.nonzero(ann.masks[0])
    assert abs(xs.mean() - 31.3) < 0.1 and abs(ys.mean() - 23.8) < 0.1
    r = 60.0 * 0.05 / np.sqrt(0.6**2 - 0.05**2)  # tangent-cone radius, pixels
    assert abs(len(xs) / (np.pi * r * 61 / 60 * r) - 1) < 0.08


def test_fully_hidden_and_outside(annotator, tmp_path):
    front = card(tmp_path, "front", 5.3, 50.7, 5.3, 40.7, 0.5, obj_id=1, inst=0)
    hidden = card(tmp_path, "hidden", 15.3, 25.7, 15.3, 25.7, 1.0, obj_id=2, inst=1)
    outside = card(tmp_path, "outside", 100.3, 120.7, 10.3, 20.7, 1.0, obj_id=3, inst=2)  # right of image
    behind = MeshInstance("behind", hidden.mesh_path, hidden.mesh_key, pose([0, 0, -1.0]), obj_id=4, inst=3)
    annotator.load(RenderScene(meshes=(front, hidden, outside, behind)))
    ann = annotator.annotate(camera(), DELTA)
    g = ann.instances
    check(g[1], (100, 100, 0, [-1, -1, -1, -1], [-1, -1, -1, -1]))
    assert ann.masks[1].sum() == 100 and not ann.masks_visib[1].any()
    check(g[2], (200, 0, 0, [-1, -1, -1, -1], [-1, -1, -1, -1]))  # 20 x 10 px on the 3x canvas
    assert not ann.masks[2].any()
    check(g[3], (0, 0, 0, [-1, -1, -1, -1], [-1, -1, -1, -1]))
    assert annotator.visib_fract(camera(), 1, DELTA) == 0.0
    assert annotator.visib_fract(camera(), 2, DELTA) == 0.0
    assert annotator.visib_fract(camera(), 0, DELTA) == 1.0


def test_mesh_cache_across_loads_and_shared_meshes(annotator, tmp_path, monkeypatch):
    import specsynth.annotate.engine as annotate_mod

    reads = []
    real = annotate_mod.read_mesh
    monkeypatch.setattr(annotate_mod, "read_mesh", lambda p: reads.append(p) or real(p))
    a = card(tmp_path, "cache", 10.3, 20.7, 10.3, 20.7, 1.0, obj_id=1, inst=0)  # cols/rows 11..20
    twin = MeshInstance("twin", a.mesh_path, a.mesh_key, pose(np.array(a.matrix[:3, 3]) + [0.2, 0, 0]), obj_id=1, inst=1)
    annotator.load(RenderScene(meshes=(a, twin)))
    ann = annotator.annotate(camera(), DELTA)
    np.testing.assert_array_equal(ann.masks[0], rect(11, 20, 11, 20))
    np.testing.assert_array_equal(ann.masks[1], rect(31, 40, 11, 20))  # same mesh, 20 px right
    # a new arrangement with the same mesh: no re-read, new poses honoured
    moved = MeshInstance("cache", a.mesh_path, a.mesh_key, pose(np.array(a.matrix[:3, 3]) + [0, 0.1, 0]), obj_id=1, inst=0)
    annotator.load(RenderScene(meshes=(moved,)))
    ann = annotator.annotate(camera(), DELTA)
    assert len(ann.instances) == 1
    np.testing.assert_array_equal(ann.masks[0], rect(11, 20, 21, 30))
    assert reads == [a.mesh_path]


def test_camera_size_mismatch(annotator, analytic_scene):
    annotator.load(analytic_scene)
    bad = CameraIR(K=as_tuple(K), width=W + 1, height=H, R_w2c=as_tuple(np.eye(3)), t_w2c=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError):
        annotator.annotate(bad, DELTA)
    with pytest.raises(ValueError):
        annotator.annotate(camera(), DELTA, occluders="nothing")


def bop_reference(annotator, cam, delta):
    """calc_gt_info.py step by step: every object alone on the full 3x canvas, full-image scene depth."""
    from specsynth.annotate.engine import depth_to_dist_factor

    annotator._set_camera(cam)
    depth = annotator._render(cam, annotator._nodes, 0, 0, W, H)
    factor = depth_to_dist_factor(cam.K_array, W, H)
    dist_im = depth * factor
    out = []
    for node in annotator._object_nodes:
        large = annotator._render(cam, [node], -W, -H, 2 * W, 2 * H)
        dist_gt = large[H : 2 * H, W : 2 * W] * factor
        d_diff = dist_gt.astype(np.float32) - dist_im.astype(np.float32)
        visib = ((d_diff <= delta) | (dist_im == 0)) & (dist_gt > 0)
        mask_large = large > 0
        px_all, px_visib = int(mask_large.sum()), int(visib.sum())
        px_valid = int((dist_im[dist_gt > 0] > 0).sum())
        bbox = bbox_visib = [-1, -1, -1, -1]
        if px_visib > 0:
            ys, xs = mask_large.nonzero()
            xs, ys = xs - W, ys - H
            bbox = [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]
            ys, xs = visib.nonzero()
            bbox_visib = [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]
        out.append((px_all, px_valid, px_visib, bbox, bbox_visib))
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_windowed_renders_equal_full_3x_canvas(annotator, tmp_path, seed):
    """Clutter with truncated, occluded and near-plane-crossing objects: same numbers as BOP's way."""
    rng = np.random.default_rng(seed)
    shapes = [
        write_trimesh(tmp_path / "s0.ply", trimesh.creation.icosphere(2, 0.05)),
        write_trimesh(tmp_path / "s1.ply", trimesh.creation.box(extents=[0.12, 0.05, 0.08])),
        write_trimesh(tmp_path / "s2.ply", trimesh.creation.cylinder(0.03, 0.15, sections=24)),
    ]
    meshes = [MeshInstance("floor", write_trimesh(tmp_path / "floor.ply", trimesh.creation.box(extents=[3, 3, 0.01])),
                           "k-floor", pose([0, 0, -0.005]))]
    for i in range(8):
        R, _ = camera_pose((0, 0, 0), *rng.uniform(0, 360, 2), 1.0, rng.uniform(0, 360))
        k = i % 3
        meshes.append(MeshInstance(f"o{i}", shapes[k], f"k-s{k}", pose([*rng.uniform(-0.25, 0.25, 2), 0.04], R), obj_id=k + 1, inst=i))
    annotator.load(RenderScene(meshes=tuple(meshes)))
    K2 = np.array([[45.0, 0, 31.7], [0, 45.0, 23.2], [0, 0, 1]])
    for view in range(3):
        R, t = camera_pose((0, 0, 0), rng.uniform(0, 360), rng.uniform(15, 60), rng.uniform(0.25, 0.6), rng.uniform(-30, 30))
        cam = camera(K=K2, R=R, t=t, near=0.05)
        ann = annotator.annotate(cam, DELTA)
        ref = bop_reference(annotator, cam, DELTA)
        got = [(g.px_count_all, g.px_count_valid, g.px_count_visib, g.bbox_obj, g.bbox_visib) for g in ann.instances]
        assert got == ref
        for g in ann.instances:
            assert g.visib_fract == (g.px_count_visib / g.px_count_all if g.px_count_all else 0.0)
            assert annotator.visib_fract(cam, g.inst, DELTA) == g.visib_fract


def _ray_depth(tris: np.ndarray, origin: np.ndarray, dirs: np.ndarray, near: float) -> np.ndarray:
    """z-depth of the first surface past the near plane along each ray (``dirs`` have camera z = 1,
    so the ray parameter is the z-depth), either face; 0 on a miss. Moller-Trumbore in numpy."""
    out = np.full(len(dirs), np.inf)
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    s = origin - v0
    q = np.cross(s, e1)
    t_q = np.einsum("ij,ij->i", e2, q)
    for c in range(0, len(dirs), 2048):
        d = dirs[c : c + 2048]
        p = np.cross(d[:, None, :], e2[None])
        det = np.einsum("tj,rtj->rt", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("tj,rtj->rt", s, p) * inv
            v = (d @ q.T) * inv
            t = t_q[None] * inv
        ok = (np.abs(det) > 1e-15) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= near)
        out[c : c + 2048] = np.where(ok, t, np.inf).min(1)
    return np.where(np.isfinite(out), out, 0.0)


def raycast_reference(meshes, cam, delta):
    """calc_gt_info.py's numbers from rays cast through every pixel centre of the 3x canvas in
    numpy: nothing of the annotator (its OpenGL renders, windows or depth factors) is used."""
    R, t = np.asarray(cam.R_w2c), np.asarray(cam.t_w2c)
    eye = -R.T @ t
    u, v = np.meshgrid(np.arange(-W, 2 * W, dtype=float), np.arange(-H, 2 * H, dtype=float))
    d_cam = np.stack([u.ravel(), v.ravel(), np.ones(u.size)], 1) @ np.linalg.inv(cam.K_array).T
    dirs = d_cam @ R  # world directions, camera z = 1
    factor = np.linalg.norm(d_cam, axis=1).reshape(u.shape)
    depth = {}
    for m in meshes:
        tm = trimesh.load(m.mesh_path, force="mesh", process=False)
        world = np.asarray(tm.vertices, float) @ np.asarray(m.pose)[:3, :3].T + np.asarray(m.pose)[:3, 3]
        depth[m.name] = _ray_depth(world[np.asarray(tm.faces)], eye, dirs, cam.near).reshape(u.shape)
    hits = np.stack(list(depth.values()))
    scene = np.where(hits > 0, hits, np.inf).min(0)
    scene = np.where(np.isfinite(scene), scene, 0.0)[H : 2 * H, W : 2 * W] * factor[H : 2 * H, W : 2 * W]
    out = []
    for m in sorted((m for m in meshes if m.obj_id is not None), key=lambda m: m.inst):
        large = depth[m.name] * factor
        gt = large[H : 2 * H, W : 2 * W]
        visib = ((gt - scene <= delta) | (scene == 0)) & (gt > 0)
        out.append((int((large > 0).sum()), int(visib.sum())))
    return out


def test_annotations_agree_with_rays_cast_through_the_pixels(annotator, tmp_path):
    """Truncated, occluded objects on a floor: every object's pixel counts (whole, on the 3x
    canvas, and visible) agree with rays cast in numpy, up to the pixels along its outline that
    a rasteriser and a ray through the pixel centre may decide differently."""
    rng = np.random.default_rng(5)
    shapes = [
        write_trimesh(tmp_path / "s0.ply", trimesh.creation.icosphere(2, 0.05)),
        write_trimesh(tmp_path / "s1.ply", trimesh.creation.box(extents=[0.12, 0.05, 0.08])),
        write_trimesh(tmp_path / "s2.ply", trimesh.creation.cylinder(0.03, 0.15, sections=24)),
    ]
    meshes = [MeshInstance("floor", write_trimesh(tmp_path / "floor.ply", trimesh.creation.box(extents=[3, 3, 0.01])),
                           "k-floor", pose([0, 0, -0.005]))]
    for i in range(6):
        R, _ = camera_pose((0, 0, 0), *rng.uniform(0, 360, 2), 1.0, rng.uniform(0, 360))
        meshes.append(MeshInstance(f"o{i}", shapes[i % 3], f"k-s{i % 3}", pose([*rng.uniform(-0.2, 0.2, 2), 0.04], R),
                                   obj_id=i % 3 + 1, inst=i))
    annotator.load(RenderScene(meshes=tuple(meshes)))
    K2 = np.array([[45.0, 0, 31.7], [0, 45.0, 23.2], [0, 0, 1]])
    occluded = 0
    for view in range(2):
        R, t = camera_pose((0, 0, 0), rng.uniform(0, 360), rng.uniform(20, 50), rng.uniform(0.35, 0.6), rng.uniform(-30, 30))
        cam = camera(K=K2, R=R, t=t, near=0.05)
        got = [(g.px_count_all, g.px_count_visib) for g in annotator.annotate(cam, DELTA).instances]
        ref = raycast_reference(meshes, cam, DELTA)
        for (all_g, vis_g), (all_r, vis_r) in zip(got, ref):
            edge = 1 + 0.02 * all_r  # they agree exactly here; a rasteriser may round an outline pixel otherwise
            assert abs(all_g - all_r) <= edge and abs(vis_g - vis_r) <= edge, (view, got, ref)
            occluded += vis_r < all_r - edge
    assert occluded >= 1  # the scene does test occlusion


def test_near_plane_crossing_and_canvas_overflow(annotator, tmp_path):
    bar = trimesh.creation.box(extents=[0.02, 0.02, 0.6])  # z from 0.0 to 0.6: crosses near = 0.05
    bar_path = write_trimesh(tmp_path / "bar.ply", bar)
    meshes = (
        MeshInstance("bar", bar_path, "k-bar", pose([0.03, -0.02, 0.3]), obj_id=1, inst=0),
        card(tmp_path, "huge", -500.3, 500.7, -400.3, 400.7, 1.0, obj_id=2, inst=1),  # beyond the 3x canvas
        MeshInstance("gone", bar_path, "k-bar", pose([0.0, 0.0, -0.4]), obj_id=1, inst=2),  # behind the camera
    )
    annotator.load(RenderScene(meshes=meshes))
    cam = camera(near=0.05)
    ann = annotator.annotate(cam, DELTA)
    ref = bop_reference(annotator, cam, DELTA)
    got = [(g.px_count_all, g.px_count_valid, g.px_count_visib, g.bbox_obj, g.bbox_visib) for g in ann.instances]
    assert got == ref
    huge = ann.instances[1]
    assert huge.px_count_all == 9 * W * H and huge.bbox_obj == [-W, -H, 3 * W - 1, 3 * H - 1]
    assert ann.instances[0].px_count_all > ann.masks[0].sum() > 0  # the bar leaves the image
    assert ann.instances[2].px_count_all == 0


def test_free_distance_finds_cameras_inside_walls_and_objects():
    """room2's wall boxes are 10 cm thick: a camera in one is 5 cm from surfaces on two sides
    (the old annotation engine culled those back faces and saw through the wall)."""
    from pathlib import Path

    from specsynth.annotate.engine import Annotator
    from specsynth.model.ir import RenderScene
    from specsynth.scenes import load_scene

    d = load_scene("room2", Path("."))
    a = Annotator(32, 24)
    try:
        a.load(RenderScene(meshes=d.meshes, lights=d.lights, world=d.world))
        assert a.free_distance((0.0, 2.55, 1.2)) == pytest.approx(0.05, abs=0.01)  # inside the north wall
        assert a.free_distance((0.0, -2.55, 1.2)) == pytest.approx(0.05, abs=0.01)
        assert a.free_distance((0.0, 0.0, 0.03)) == pytest.approx(0.03, abs=0.005)  # 3 cm over the floor
        assert a.free_distance((0.0, 0.0, 1.3)) > 0.2  # in the room
    finally:
        a.close()


@pytest.mark.parametrize("step", [1, 8])
def test_near_share_measures_what_fills_the_view_in_front_and_leaves_labels_alone(annotator, tmp_path, step):
    """A wall card 0.4 m in front of the camera over columns 0-33 of 64, a backdrop at 2 m: 34/64
    of the image is nearer than 0.9 m at full size, and 4/8 from the 1/8 render, whose pixel centres
    fall on columns 3.5, 11.5, ... (without the half-pixel shift, on 0, 8, ..., 32: 5/8); none of
    it is nearer than 0.3 m, all of it nearer than 3 m; the labels after it are those before it."""
    wall = card(tmp_path, "wall", -10.0, 33.5, -10.0, 60.0, 0.4)
    A = card(tmp_path, "A", 40.3, 50.7, 8.3, 28.7, 1.0, obj_id=1, inst=0)
    backdrop = card(tmp_path, "backdrop", -200, 300, -200, 300, 2.0)
    annotator.load(RenderScene(meshes=(wall, A, backdrop)))
    cam = camera()
    before = annotator.annotate(cam, DELTA)
    assert annotator.near_share(cam, 0.9, step=step) == pytest.approx(34 / 64 if step == 1 else 0.5)
    assert annotator.near_share(cam, 0.3, step=step) == 0.0
    assert annotator.near_share(cam, 3.0, step=step) == 1.0
    after = annotator.annotate(cam, DELTA)
    assert after.instances == before.instances and np.array_equal(after.masks, before.masks)
    assert annotator.visib_fract(cam, 0, DELTA) == before.instances[0].visib_fract == 1.0

"""Real pybullet runs of specsynth.physics.arrange on small scenes built from trimesh primitives."""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import time
from pathlib import Path

import numpy as np
import pybullet as p
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from specsynth.assets import meshio
from specsynth.assets.resolve import ObjectAsset
from specsynth.model.ir import MaterialIR, MeshInstance, WorldIR, as_tuple
from specsynth.physics import (
    ArrangeError,
    _Body,
    _simulate,
    _World,
    _world_box,
    arrange,
    build_collision_model,
    collider_region,
    faces_in_region,
    quat_angle,
)
from specsynth.scenes.types import SceneDesc, Stage
from specsynth.spec.models import Arrangements, Physics

TABLE_TOP = 0.75  # m


# --------------------------------------------------------------------------- builders


def _write(tm: trimesh.Trimesh, path: Path) -> tuple[str, str]:
    mesh = meshio.MeshData(
        vertices=np.asarray(tm.vertices, dtype=np.float32),
        faces=np.asarray(tm.faces, dtype=np.int32),
    )
    meshio.write_mesh(path, mesh)
    return str(path), hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def make_asset(tm: trimesh.Trimesh, tmp: Path, name: str, obj_id: int = 1) -> ObjectAsset:
    path, key = _write(tm, tmp / f"{name}.ply")
    lo, hi = tm.bounds
    v = np.asarray(tm.vertices)
    diameter = float(max(np.linalg.norm(v - x, axis=1).max() for x in v[:: max(1, len(v) // 200)]))
    return ObjectAsset(
        obj_id=obj_id,
        name=name,
        mesh_path=path,
        mesh_key=key,
        material=MaterialIR(),
        diameter=diameter,
        bbox_min=tuple(float(x) for x in lo),
        extents=tuple(float(x) for x in hi - lo),
        source=f"test:{name}",
    )


def make_table_scene(
    tmp: Path, top=(1.0, 0.8), thickness=0.02, stage_half=(0.4, 0.3), stage_center=(0.0, 0.0), floor=True
) -> tuple[SceneDesc, Stage]:
    """A table top (box, `thickness` thick, upper face at TABLE_TOP) over an optional floor."""
    meshes = []
    top_box = trimesh.creation.box(extents=(top[0], top[1], thickness))
    path, key = _write(top_box, tmp / "table.ply")
    pose = np.eye(4)
    pose[2, 3] = TABLE_TOP - thickness / 2
    meshes.append(MeshInstance(name="table", mesh_path=path, mesh_key=key, pose=as_tuple(pose)))
    if floor:
        fl = trimesh.creation.box(extents=(6.0, 6.0, 0.1))
        path, key = _write(fl, tmp / "floor.ply")
        pose = np.eye(4)
        pose[2, 3] = -0.05
        meshes.append(MeshInstance(name="floor", mesh_path=path, mesh_key=key, pose=as_tuple(pose)))
    cx, cy = stage_center
    hx, hy = stage_half
    stage = Stage(
        name="table_top",
        polygon=((cx - hx, cy - hy), (cx + hx, cy - hy), (cx + hx, cy + hy), (cx - hx, cy + hy)),
        height=TABLE_TOP,
    )
    scene = SceneDesc(name="test_table", meshes=tuple(meshes), lights=(), world=WorldIR(), stages={stage.name: stage})
    return scene, stage


def small_objects(tmp: Path) -> list[ObjectAsset]:
    box = trimesh.creation.box(extents=(0.08, 0.05, 0.04))
    cyl = trimesh.creation.cylinder(radius=0.03, height=0.09, sections=24)
    # Off-centre model origin: the returned pose must still map model coordinates exactly.
    off = trimesh.creation.box(extents=(0.06, 0.06, 0.05))
    off.apply_translation((0.02, -0.01, 0.03))
    return [make_asset(box, tmp, "box", 1), make_asset(cyl, tmp, "cyl", 2), make_asset(off, tmp, "offbox", 3)]


def fast_arrangements(**phys) -> Arrangements:
    return Arrangements(drop_height=(0.05, 0.3), physics=Physics(max_time=4.0, **phys))


def world_vertices(asset: ObjectAsset, pose: np.ndarray) -> np.ndarray:
    v = meshio.read_mesh(asset.mesh_path).vertices.astype(np.float64)
    return v @ pose[:3, :3].T + pose[:3, 3]


def max_pair_penetration(objects: list[ObjectAsset], placed) -> float:
    """Deepest penetration between placed objects, measured in a fresh client from the poses alone."""
    cid = p.connect(p.DIRECT)
    try:
        uids = []
        for i, pose in placed:
            hull = trimesh.convex.convex_hull(world_vertices(objects[i], pose))
            s = p.createCollisionShape(p.GEOM_MESH, vertices=np.asarray(hull.vertices).tolist(), physicsClientId=cid)
            u = p.createMultiBody(0.0, s, physicsClientId=cid)
            # Bullet reports distance minus both margins; a tiny margin keeps the reading honest.
            p.changeDynamics(u, -1, collisionMargin=1e-5, physicsClientId=cid)
            uids.append(u)
        worst = 0.0
        for a in range(len(uids)):
            for b in range(a + 1, len(uids)):
                for pt in p.getClosestPoints(uids[a], uids[b], 0.01, physicsClientId=cid):
                    worst = max(worst, -pt[8])
        return worst
    finally:
        p.disconnect(physicsClientId=cid)


def check_valid(result, objects, stage: Stage) -> None:
    assert [i for i, _ in result.placed] == sorted(i for i, _ in result.placed)
    for i, pose in result.placed:
        assert pose.shape == (4, 4)
        assert np.isfinite(pose).all()
        R = pose[:3, :3]
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-6) and np.linalg.det(R) > 0
        v = world_vertices(objects[i], pose)
        centre = v.mean(0)
        assert stage.contains(pose[:2, 3]) or stage.contains(centre[:2])
        assert v[:, 2].min() >= stage.height - 0.005
    assert max_pair_penetration(objects, result.placed) <= 0.002


# --------------------------------------------------------------------------- tests


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("physics")
    scene, stage = make_table_scene(tmp)
    return tmp, scene, stage, small_objects(tmp)


def test_objects_rest_on_stage_without_penetration(table):
    tmp, scene, stage, assets = table
    objects = assets * 2  # two instances per model
    res = arrange(scene, stage, objects, fast_arrangements(), "random", np.random.default_rng(1))
    assert res.removed + len(res.placed) == len(objects)
    assert res.sim_seconds > 0
    check_valid(res, objects, stage)
    # Resting objects touch something: the lowest point of an object lying on the table is on it
    # (within margins), not hovering.
    lows = [world_vertices(objects[i], T)[:, 2].min() for i, T in res.placed]
    assert min(lows) == pytest.approx(TABLE_TOP, abs=0.002)


def test_model_frame_pose_is_exact(table):
    """Transforming the mesh by the returned pose puts its lowest point on the table top."""
    tmp, scene, stage, assets = table
    offbox = assets[2]
    res = arrange(scene, stage, [offbox], fast_arrangements(), "canonical", np.random.default_rng(3))
    (i, pose), = res.placed
    v = world_vertices(offbox, pose)
    assert v[:, 2].min() == pytest.approx(TABLE_TOP, abs=0.0015)
    assert v[:, 2].max() == pytest.approx(TABLE_TOP + 0.05, abs=0.0015)


def test_canonical_boxes_stay_upright(table):
    tmp, scene, stage, assets = table
    objects = [assets[0], assets[2], assets[0]]
    res = arrange(scene, stage, objects, fast_arrangements(), "canonical", np.random.default_rng(5))
    assert len(res.placed) == 3
    for _, pose in res.placed:
        # Model Z stays world Z up to yaw: the third column of R is (0, 0, 1).
        assert pose[2, 2] > np.cos(np.radians(2.0))
    check_valid(res, objects, stage)


def test_standing_objects_start_on_the_stage_and_stay_upright(table):
    """placement: stand puts tall objects (a bottle-like cylinder, a tall box) on the stage upright,
    as objects stand on a real desk; the same objects dropped from 30-50 cm topple. Both are real
    pybullet runs over the same seeds."""
    tmp, scene, stage, _ = table
    tall = [make_asset(trimesh.creation.cylinder(radius=0.022, height=0.16, sections=24), tmp, "bottle", 4),
            make_asset(trimesh.creation.box(extents=(0.035, 0.05, 0.15)), tmp, "tallbox", 5)]
    stand = Arrangements(placement="stand", physics=Physics(max_time=4.0))
    drop = Arrangements(drop_height=(0.3, 0.5), physics=Physics(max_time=4.0))
    toppled = 0
    for seed in range(4):
        res = arrange(scene, stage, tall * 2, stand, "canonical", np.random.default_rng(seed))
        assert len(res.placed) == 4 and res.redropped == 0
        assert all(pose[2, 2] > np.cos(np.radians(3.0)) for _, pose in res.placed)
        check_valid(res, tall * 2, stage)
        dropped = arrange(scene, stage, tall * 2, drop, "canonical", np.random.default_rng(seed))
        toppled += sum(pose[2, 2] < np.cos(np.radians(45.0)) for _, pose in dropped.placed)
    assert toppled >= 2


def _run_in_child(args):
    scene, stage, objects, arr, orientation, seed = args
    res = arrange(scene, stage, objects, arr, orientation, np.random.default_rng(seed))
    return [(i, T.tobytes()) for i, T in res.placed], res.removed, res.redropped


def test_deterministic_across_processes(table):
    tmp, scene, stage, assets = table
    args = (scene, stage, assets * 2, fast_arrangements(), "random", 11)
    here = _run_in_child(args)
    again = _run_in_child(args)
    with mp.get_context("spawn").Pool(1) as pool:
        there = pool.apply(_run_in_child, (args,))
    assert here == again == there
    other = _run_in_child(args[:-1] + (12,))
    assert other[0] != here[0]


def test_thin_block_does_not_tunnel_through_thin_table(tmp_path):
    # A big table and stage, so that a block that is gone can only have gone *through* the top.
    scene, stage = make_table_scene(tmp_path, top=(3.0, 3.0), stage_half=(1.3, 1.3), thickness=0.02, floor=False)
    jenga = make_asset(trimesh.creation.box(extents=(0.075, 0.025, 0.015)), tmp_path, "jenga")
    arr = Arrangements(drop_height=(0.5, 0.5), physics=Physics(max_time=3.0, max_redrops=0, on_invalid="remove"))
    for seed in range(4):
        # Random orientations: edge- and corner-first impacts are the ones that tunnel.
        res = arrange(scene, stage, [jenga] * 3, arr, "random", np.random.default_rng(seed))
        assert res.invalid_reasons.get("fell_through", 0) == 0, f"seed {seed}: {res.invalid_reasons}"
        for i, pose in res.placed:
            assert world_vertices(jenga, pose)[:, 2].min() >= TABLE_TOP - 0.003


def test_too_small_stage_removes_or_raises_never_hangs(tmp_path):
    # A 2 cm stage on a big table: a flat box can rest over it, balls dropped onto the box roll
    # off, and so do their re-drops.
    scene, stage = make_table_scene(tmp_path, stage_half=(0.01, 0.01))
    box = make_asset(trimesh.creation.box(extents=(0.1, 0.1, 0.05)), tmp_path, "box")
    ball = make_asset(trimesh.creation.icosphere(subdivisions=2, radius=0.04), tmp_path, "ball")
    objects = [box, ball, ball, ball]
    arr = Arrangements(drop_height=(0.02, 0.1), physics=Physics(max_time=2.0, max_redrops=1))
    t0 = time.monotonic()
    try:
        res = arrange(scene, stage, objects, arr, "canonical", np.random.default_rng(0))
    except ArrangeError as e:
        assert "table_top" in str(e)
    else:
        assert res.removed >= 1 and res.redropped >= 1
        assert res.removed + len(res.placed) == len(objects)
        assert sum(res.invalid_reasons.values()) == res.removed + res.redropped
        check_valid(res, objects, stage)
    assert time.monotonic() - t0 < 30


def test_unsupported_stage_raises_clear_error(tmp_path):
    # The stage lies beside the table over the void: everything falls, nothing can be kept.
    scene, stage = make_table_scene(tmp_path, stage_center=(2.0, 0.0), stage_half=(0.1, 0.1), floor=False)
    box = make_asset(trimesh.creation.box(extents=(0.05, 0.05, 0.05)), tmp_path, "box")
    arr = Arrangements(drop_height=(0.05, 0.1), physics=Physics(max_time=2.0, max_redrops=2))
    with pytest.raises(ValueError, match="table_top"):
        arrange(scene, stage, [box, box], arr, "canonical", np.random.default_rng(0))


@pytest.mark.parametrize("seed", [0, 2, 3])
def test_remove_mode_counts_without_redrops(tmp_path, seed):
    """on_invalid: remove gives an object up after its first invalid drop: counted in `removed`
    and its reason, never re-dropped. A 10 cm box over a 2 cm stage stays (its centre is over the
    stage); the balls dropped after it land on it and roll off the stage (arrange succeeds with
    these seeds: the box is kept)."""
    scene, stage = make_table_scene(tmp_path, stage_half=(0.01, 0.01))
    box = make_asset(trimesh.creation.box(extents=(0.1, 0.1, 0.05)), tmp_path, "box")
    ball = make_asset(trimesh.creation.icosphere(subdivisions=2, radius=0.04), tmp_path, "ball")
    objects = [box, ball, ball, ball]

    def run(mode):
        arr = Arrangements(drop_height=(0.02, 0.1), physics=Physics(max_time=2.0, max_redrops=1, on_invalid=mode))
        return arrange(scene, stage, objects, arr, "canonical", np.random.default_rng(seed))

    res = run("remove")
    assert [i for i, _ in res.placed] == [0]
    assert res.removed == 3 and res.redropped == 0
    assert res.invalid_reasons == {"left_stage": 3}
    check_valid(res, objects, stage)
    # The same drops with re-drops allowed: each ball is dropped again once before it is given up.
    again = run("redrop")
    assert [i for i, _ in again.placed] == [0]
    assert again.removed == 3 and again.redropped == 3
    assert sum(again.invalid_reasons.values()) == again.removed + again.redropped == 6


def test_empty_object_list(table):
    tmp, scene, stage, _ = table
    res = arrange(scene, stage, [], fast_arrangements(), "canonical", np.random.default_rng(0))
    assert res.placed == [] and res.removed == 0 and res.settled


def test_decomposition_is_cached_once_per_mesh(tmp_path, monkeypatch):
    scene, stage = make_table_scene(tmp_path)
    ring = make_asset(trimesh.creation.annulus(r_min=0.02, r_max=0.035, height=0.02, sections=16), tmp_path, "ring")
    cache = tmp_path / "collision"
    arr = fast_arrangements(collision="decomposition")
    res1 = arrange(scene, stage, [ring], arr, "canonical", np.random.default_rng(2), collision_cache=cache)
    files = list(cache.glob("*.npz"))
    assert [f.name for f in files] == [f"{ring.mesh_key}.npz"]
    # A second run must not decompose again, and gives the same poses from the cached parts.
    import coacd

    monkeypatch.setattr(coacd, "run_coacd", lambda *a, **k: pytest.fail("decomposition recomputed"))
    res2 = arrange(scene, stage, [ring], arr, "canonical", np.random.default_rng(2), collision_cache=cache)
    assert [T.tobytes() for _, T in res1.placed] == [T.tobytes() for _, T in res2.placed]
    check_valid(res2, [ring], stage)
    # Canonical flat ring lands flat.
    assert res2.placed[0][1][2, 2] > np.cos(np.radians(2.0))


# --------------------------------------------------------------------------- colliders near the stage

@settings(max_examples=120, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 60), where=st.sampled_from(["random", "around", "away"]))
def test_faces_in_region_keeps_exactly_the_faces_whose_box_meets_the_region(seed, n, where):
    rng = np.random.default_rng(seed)
    v = rng.uniform(-3.0, 3.0, size=(3 * n, 3))
    f = rng.permutation(3 * n).reshape(n, 3)
    lo = rng.uniform(-2.0, 1.0, size=3)
    region = np.array([lo, lo + rng.uniform(0.0, 2.0, size=3)])
    if where == "around":  # the whole mesh inside the region (its early return)
        region = np.array([v.min(axis=0) - rng.uniform(0, 1, 3), v.max(axis=0) + rng.uniform(0, 1, 3)])
    elif where == "away":  # the whole mesh beside the region along one axis, or just touching it
        axis = int(rng.integers(3))
        region[:, axis] = v[:, axis].max() + np.array([rng.choice([0.0, 0.5]), 1.0])
    kept = {tuple(t) for t in faces_in_region(v, f, region).tolist()}
    for t in f.tolist():
        box_lo, box_hi = v[t].min(axis=0), v[t].max(axis=0)
        meets = bool(np.all(box_hi >= region[0]) and np.all(box_lo <= region[1]))
        assert (tuple(t) in kept) == meets
        if any(np.all((region[0] <= v[i]) & (v[i] <= region[1])) for i in t):
            assert tuple(t) in kept  # a face with a corner inside is always kept


def test_colliders_are_cut_to_the_stage_neighbourhood(tmp_path, monkeypatch):
    """Bullet gets the table and what is near or above it, not a cupboard across the room nor
    the floor under the table (nothing alive reaches below the stage), and the objects still
    rest on the table."""
    scene, stage = make_table_scene(tmp_path)
    far = trimesh.creation.box(extents=(0.5, 0.5, 2.0))
    path, key = _write(far, tmp_path / "cupboard.ply")
    pose = np.eye(4)
    pose[:3, 3] = (4.0, 0.0, 1.0)
    above = trimesh.creation.box(extents=(1.0, 0.8, 0.02))
    path_a, key_a = _write(above, tmp_path / "shelf_above.ply")
    pose_a = np.eye(4)
    pose_a[2, 3] = 2.0
    scene = SceneDesc(name=scene.name, lights=(), world=WorldIR(), stages=scene.stages, meshes=scene.meshes + (
        MeshInstance(name="cupboard", mesh_path=path, mesh_key=key, pose=as_tuple(pose)),
        MeshInstance(name="shelf_above", mesh_path=path_a, mesh_key=key_a, pose=as_tuple(pose_a))))
    given_to_bullet = []
    real = _World.add_collider
    monkeypatch.setattr(_World, "add_collider", lambda self, v, f: given_to_bullet.append(v[f]) or real(self, v, f))
    objects = small_objects(tmp_path)
    res = arrange(scene, stage, objects, fast_arrangements(), "canonical", np.random.default_rng(3))
    check_valid(res, objects, stage)
    tris = np.concatenate(given_to_bullet)
    assert np.isclose(tris[..., 2], 2.01).any()  # the shelf above the table is there
    assert tris[..., 0].max() < 3.0  # the cupboard is not
    assert tris[..., 2].min() > TABLE_TOP - 0.2  # nor the floor
    region = collider_region(stage, max(np.linalg.norm(o.extents) / 2 for o in objects))
    assert region[0, 2] < TABLE_TOP and region[1, 2] == np.inf


def test_a_stage_on_a_top_far_larger_than_the_reach_keeps_its_triangles(tmp_path):
    """A 30 m slab is a few huge triangles, none with a corner near the stage: still kept."""
    scene, stage = make_table_scene(tmp_path, top=(30.0, 30.0), floor=False)
    objects = small_objects(tmp_path)
    res = arrange(scene, stage, objects, fast_arrangements(), "canonical", np.random.default_rng(5))
    assert len(res.placed) == len(objects)
    check_valid(res, objects, stage)


# --------------------------------------------------------------------------- settling


def _axis_angle_quat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    return np.array([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


@settings(max_examples=200, deadline=None)
@given(
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    axis=st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda v: np.linalg.norm(v) > 0.1),
    angle=st.floats(0, np.pi),
    flip=st.booleans(),
)
def test_quat_angle_is_the_angle_of_the_relative_rotation(q, axis, angle, flip):
    q0 = np.array(q) / np.linalg.norm(q)
    q1 = _quat_mul(q0, _axis_angle_quat(np.array(axis), angle))
    q1 = -q1 if flip else q1  # q and -q are the same orientation
    assert quat_angle(q0, q1) == pytest.approx(angle, abs=2e-6)


class _Jittering:
    """pybullet, except that after each step the body spins at +-``spin`` rad/s about x in turn: the
    contact jitter measured on the demo's piles (their centres still within 0.4 mm over 4 s)."""

    def __init__(self, spin: float):
        self.spin, self.sign, self.uid = spin, 1.0, -1

    def __getattr__(self, name):
        return getattr(p, name)

    def stepSimulation(self, physicsClientId):
        p.stepSimulation(physicsClientId=physicsClientId)
        if self.uid >= 0:
            v, _ = p.getBaseVelocity(self.uid, physicsClientId=physicsClientId)
            p.resetBaseVelocity(self.uid, v, [self.sign * self.spin, 0, 0], physicsClientId=physicsClientId)
            self.sign = -self.sign


def _slide(tmp: Path, speed: float, max_time: float = 1.5, jitter: float = 0.0) -> tuple[int, bool]:
    """A box on a frictionless floor pushed at ``speed`` m/s along x: (steps, settled)."""
    engine = _Jittering(jitter)
    scene, stage = make_table_scene(tmp, top=(6.0, 6.0), stage_half=(2.5, 2.5), floor=False)
    asset = make_asset(trimesh.creation.box(extents=(0.1, 0.1, 0.1)), tmp, "slider")
    world = _World(engine, Physics(friction=0.0, restitution=0.0, max_time=max_time), tmp)
    try:
        world.setup()
        top = meshio.read_mesh(scene.meshes[0].mesh_path)
        T = np.asarray(scene.meshes[0].pose).reshape(4, 4)
        world.add_collider(top.vertices.astype(np.float64) @ T[:3, :3].T + T[:3, 3], top.faces)
        body = _Body(0, build_collision_model(asset))
        world.add_object(body, np.array([0.0, 0.0, TABLE_TOP + 0.05 + 0.0005]), np.eye(3))
        p.resetBaseVelocity(body.uid, [speed, 0.0, 0.0], [0.0, 0.0, 0.0], physicsClientId=world.cid)
        engine.uid = body.uid if jitter else -1
        steps, settled, lost = _simulate(world, [body], stage)
        assert not lost
        return steps, settled
    finally:
        world.close()


def test_settling_is_judged_on_mean_speed_over_the_hold_window(tmp_path):
    # Default thresholds: 0.01 m/s over 0.25 s. Bullet's default damping slows the slider by ~4 %/s.
    steps, settled = _slide(tmp_path, 0.02)
    assert not settled and steps == round(1.5 * 240)
    steps, settled = _slide(tmp_path, 0.007)
    assert settled and steps <= round(0.25 * 240) + 5


def test_a_jittering_object_at_rest_counts_as_settled(tmp_path):
    # Angular speed 0.5 rad/s at every step, five times the threshold, but no net turn.
    steps, settled = _slide(tmp_path, 0.0, jitter=0.5)
    assert settled and steps <= round(0.25 * 240) + 5


def _f(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_subnormal=False)


@settings(max_examples=200, deadline=None)
@given(vertices=st.lists(st.tuples(*[_f(-3, 3)] * 3), min_size=1, max_size=50),
       q=st.tuples(*[_f(-1, 1)] * 4).filter(lambda q: np.linalg.norm(q) > 0.1), scale=_f(0.01, 100.0),
       stretch=st.tuples(*[_f(0.5, 2.0)] * 3), offset=st.tuples(*[_f(-10, 10)] * 3))
def test_world_box_contains_every_moved_vertex(vertices, q, scale, stretch, offset):
    v = np.asarray(vertices, np.float32)
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    T = np.eye(4)
    T[:3, :3] = R * scale * np.asarray(stretch)  # rotation, scale, shear
    T[:3, 3] = offset
    moved = v.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    box = _world_box(v, T)
    tol = 1e-9 * max(1.0, float(np.abs(moved).max()))
    assert np.all(moved >= box[0] - tol) and np.all(moved <= box[1] + tol)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(300, 3000))
def test_a_reduced_hull_keeps_the_support_in_every_sampled_direction(seed, n):
    """Vertices of the exact hull only, and the same extent along each of the sphere's directions."""
    from specsynth.physics import HULL_DIRECTIONS, _fewer_hull_vertices, fibonacci_sphere

    pts = np.random.default_rng(seed).normal(size=(n, 3)) * [0.05, 0.08, 0.03]
    exact = np.asarray(trimesh.convex.convex_hull(pts).vertices)
    fewer = _fewer_hull_vertices(exact)
    assert len(fewer) <= HULL_DIRECTIONS + 6 and set(map(tuple, fewer)) <= set(map(tuple, exact))
    d = np.concatenate([fibonacci_sphere(HULL_DIRECTIONS), np.eye(3), -np.eye(3)])
    c = exact.mean(0)
    np.testing.assert_allclose(((fewer - c) @ d.T).max(0), ((exact - c) @ d.T).max(0), atol=1e-12)
    np.testing.assert_array_equal(fewer.min(0), exact.min(0))  # the same box
    np.testing.assert_array_equal(fewer.max(0), exact.max(0))


def test_the_collision_hull_of_a_scanned_model_is_small_and_within_a_millimetre_of_the_exact_hull():
    """The real LM models (scans, 800-2,400 hull vertices) get hulls of at most HULL_DIRECTIONS
    vertices, no exact-hull vertex more than about a millimetre outside them."""
    from scipy.spatial import ConvexHull

    from specsynth.physics import HULL_DIRECTIONS, _merged_trimesh, build_collision_model
    from specsynth.assets.resolve import resolve_objects
    from specsynth.spec.models import Objects

    for asset in resolve_objects(Objects(path="dataset:lmo/models"), Path(".")):
        model = build_collision_model(asset)
        exact = _merged_trimesh(meshio.read_mesh(asset.mesh_path)).convex_hull.vertices
        assert len(exact) > 800 and len(model.hull) <= HULL_DIRECTIONS + 6
        T = model.body_from_model
        eq = ConvexHull(model.hull).equations
        outside = ((exact @ T[:3, :3].T + T[:3, 3]) @ eq[:, :3].T + eq[:, 3]).max(1)
        assert outside.max() < 1.2e-3, asset.obj_id  # measured: 0.28-1.00 mm


def test_unstacked_distractors_are_left_out_where_nothing_is_free(tmp_path):
    """Three boxes and twelve unstacked distractors standing on a stage of 30 x 30 cm:
    every object is kept, the distractors that found a free spot stand on the stage itself (none
    on another), the rest are counted as removed for "no_room". Without ``unstacked`` the same
    run starts them on top of the others, and none is left out for room."""
    scene, stage = make_table_scene(tmp_path, stage_half=(0.15, 0.15))
    box = make_asset(trimesh.creation.box(extents=(0.08, 0.08, 0.05)), tmp_path, "box", 1)
    toy = make_asset(trimesh.creation.box(extents=(0.07, 0.07, 0.05)), tmp_path, "toy", 2)
    stand = Arrangements(placement="stand", physics=Physics(max_time=3.0, max_redrops=0, on_invalid="remove"))
    objects = [box] * 3 + [toy] * 12
    res = arrange(scene, stage, objects, stand, "canonical", np.random.default_rng(3), unstacked=12)
    kept = dict(res.placed)
    assert {0, 1, 2} <= set(kept)
    assert res.invalid_reasons.get("no_room", 0) >= 1 and len(kept) > 3  # some found room
    assert res.removed + len(res.placed) == len(objects)
    assert sum(res.invalid_reasons.values()) == res.removed + res.redropped
    assert all(pose[2, 3] < TABLE_TOP + 0.03 for pose in kept.values())  # each on the stage: 2.5 cm up
    check_valid(res, objects, stage)
    stacked = arrange(scene, stage, objects, stand, "canonical", np.random.default_rng(3))
    assert "no_room" not in stacked.invalid_reasons
    assert stacked.removed + len(stacked.placed) == len(objects)

"""Physically plausible object arrangements with pybullet (paper section 3.2, "Object Arrangements").

Objects are instantiated above a stage and dropped onto the scene geometry under gravity; after
they settle, every object is checked (still over the stage, not fallen through, no NaN, no deep
penetration) and invalid ones are re-dropped or removed.

Frames: every pybullet body is built in its own *body frame*: origin at the centre of mass, axes
along the principal axes of inertia. pybullet then reports exactly the body frame's pose (no
inertial-frame offset to account for), and the world-from-model pose returned to the caller is
``T_world_body @ T_body_model``, with ``T_body_model`` fixed per mesh.

Determinism: one DIRECT client per call, bodies created in a fixed order, deterministic overlapping
pairs, and all randomness drawn from the ``rng`` argument in a fixed order. The same inputs and rng
state give bit-identical poses, in the same or in another process.
"""

from __future__ import annotations

import io
import itertools
import json
import math
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from . import processes
from .assets import meshio
from .assets.resolve import ObjectAsset
from .atomic import atomic_write_bytes
from .scenes.types import SceneDesc, Stage
from .spec.models import Arrangements, Physics

# A plausible average for household objects (wood/plastic/cardboard with air inside); only mass
# ratios matter for the arrangement, not absolute masses.
DENSITY = 500.0  # kg/m^3
GRAVITY = 9.81  # m/s^2
# Bullet inflates convex shapes by their margin (default 1 mm), so resting objects would float by
# the sum of two margins; 0.5 mm keeps the gap under a millimetre and contacts still robust.
COLLISION_MARGIN = 5e-4  # m
SOLVER_ITERATIONS = 50
# Rolling/spinning resistance as a lever arm (Bullet's unit): without it, cylinders and spheres roll
# forever and never meet the settling thresholds; 0.5 mm is of the order of wood/plastic on wood.
ROLLING_FRICTION = 5e-4  # m
SPINNING_FRICTION = 5e-4  # m
# The lowest point may sink this far below the stage before the object counts as fallen through.
FALL_THROUGH_TOLERANCE = 0.005  # m
# Largest mesh chunk handed to pybullet at once: it refuses concave meshes of ~200k vertices.
_MAX_CHUNK_FACES = 50_000
# Initial-pose attempts before giving up on a collision-free start.
_PLACEMENT_TRIES = 30
# Bounding-box clearance kept between dropped objects at their initial poses.
_START_GAP = 0.005  # m
# Sub-stepping: no point of a body may move further than this per sub-step (nor than 40 % of the
# body's thinnest extent), so fast thin objects cannot pass through thin geometry in one step.
_MAX_SUBSTEP_TRAVEL = 0.005  # m
_MAX_SUBSTEPS = 16
# An object whose centre stays outside the stage this long is given up on during the simulation
# (it rolled away; it would fail validation anyway) instead of keeping the world awake.
_LEFT_STAGE_GIVE_UP = 0.5  # simulated s
_LEFT_STAGE_CHECK = 0.05  # simulated s between those (numpy) polygon tests
# Scene colliders are cut to the stage's neighbourhood: its bounding box widened by the largest
# object's diameter plus this, from where an object counts as fallen upwards. A live object is
# over the stage, or has left it for under _LEFT_STAGE_GIVE_UP: geometry further away is not
# reached in practice, and the rest of a furnished room's triangles cost Bullet a BVH build per
# arrangement (measured: README, "Physics on furnished rooms").
_COLLIDER_REACH = 0.5  # m
_COACD_PARAMS = {"threshold": 0.05, "max_convex_hull": 32, "seed": 0, "max_ch_vertex": 128}
_DECOMPOSITION_FORMAT = 1


class ArrangeError(ValueError):
    """No object could be arranged on a stage (e.g. the stage is far too small or has no support)."""


@dataclass(frozen=True)
class ArrangeResult:
    # (index into the ``objects`` argument, 4x4 world-from-model pose in metres) of kept objects,
    # in input order.
    placed: list[tuple[int, np.ndarray]]
    removed: int  # objects given up on (invalid after their last drop)
    redropped: int  # total number of re-drops over all objects
    settled: bool  # every simulation round ended by settling, not by max_time
    sim_seconds: float  # simulated seconds over all rounds
    # Why drops were invalid, over all rounds (each re-drop and each removal has one reason):
    # "left_stage", "fell_off" (below the stage, outside it), "fell_through" (below the stage,
    # over it), "penetration", "nan"; "no_room" (an unstacked object found no free spot to start).
    invalid_reasons: dict[str, int] = field(default_factory=dict)


# --------------------------------------------------------------------------- collision models


@dataclass(frozen=True, eq=False)
class CollisionModel:
    """Everything physics needs about one mesh, in its body frame (COM origin, principal axes)."""

    mesh_key: str
    body_from_model: np.ndarray  # 4x4
    hull: np.ndarray  # (K, 3) convex-hull vertices, body frame
    parts: tuple[tuple[np.ndarray, np.ndarray], ...]  # convex parts (vertices, faces), body frame; () = use hull
    mass: float  # kg
    inertia: np.ndarray  # (3,) principal moments, kg m^2
    min_thickness: float  # m, smallest extent along a principal axis
    radius: float  # m, bounding-sphere radius about the centre of mass (read every step: precomputed)


@dataclass
class ShapeCache:
    """Collision models by mesh, held by the caller to reuse across :func:`arrange` calls.

    Building a model costs a mesh read, a convex hull and mass properties (~10-20 ms for a BOP
    model); a worker that arranges many times can keep one of these instead of rebuilding.
    """

    models: dict[tuple[str, str], CollisionModel] = field(default_factory=dict)

    def get(self, asset: ObjectAsset, collision: str, cache_dir: Path | None) -> CollisionModel:
        key = (asset.mesh_key, collision)
        if key not in self.models:
            self.models[key] = build_collision_model(asset, collision, cache_dir)
        return self.models[key]


def default_collision_cache_dir() -> Path:
    """Where convex decompositions are kept: under the assets cache when it defines one."""
    from .assets import resolve as assets

    base = getattr(assets, "cache_dir", None) or getattr(assets, "CACHE_DIR", None)
    if callable(base):
        base = base()
    if base is not None:
        return Path(base) / "collision"
    xdg = os.environ.get("XDG_CACHE_HOME")
    root = Path(xdg) if xdg else Path.home() / ".cache"
    return root / "specsynth" / "collision"


def _merged_trimesh(mesh: meshio.MeshData):
    import trimesh

    # Normalised meshes split vertices at UV/normal seams; merging by position restores
    # watertightness so that the volume and inertia are those of the solid.
    return trimesh.Trimesh(
        vertices=mesh.vertices.astype(np.float64), faces=mesh.faces.astype(np.int64), process=True
    )


def _solid_for_mass(tm):
    """The mesh itself when it bounds a solid, else its convex hull, else its bounding box."""
    import trimesh

    if tm.is_watertight and tm.is_winding_consistent and tm.volume > 1e-12:
        return tm
    try:
        hull = tm.convex_hull
        if hull.volume > 1e-12:
            return hull
    except Exception:  # qhull fails on flat or degenerate point sets
        pass
    lo, hi = tm.bounds
    ext = np.maximum(hi - lo, 1e-3)  # flat meshes still get a 1 mm thick body
    box = trimesh.creation.box(extents=ext)
    box.apply_translation((lo + hi) / 2)
    return box


# A convex hull of millions of points takes minutes; a hull of a seeded sample of them is the
# same shape within a fraction of a millimetre for collision, and is what physics needs.
HULL_MAX_POINTS = 200_000


# A scanned model's hull has 800-2,400 vertices (the LM models), and Bullet's contact search walks
# every one of them for each support query: LM-O arrangements in the furnished rooms took twice
# the CPU time with them (benchmarks/bench_arrange_scenes.py --objects lmo). The hull is kept as
# its support points in HULL_DIRECTIONS directions spread evenly over the sphere: the same extent
# along each of them and 0.3-1.0 mm inside the exact hull in between on the LM models, which are
# 95-241 mm across (test_physics).
HULL_DIRECTIONS = 1024


def fibonacci_sphere(n: int) -> np.ndarray:
    """``n`` unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (3.0 - np.sqrt(5.0)) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _fewer_hull_vertices(vertices: np.ndarray) -> np.ndarray:
    """The hull's support points in HULL_DIRECTIONS directions and along the axes (all of them when
    there are few)."""
    if len(vertices) <= HULL_DIRECTIONS // 2:
        return vertices
    centre = vertices.mean(0)
    # The six axis directions too: the hull keeps its exact box, which the model's box tests use.
    dirs = np.concatenate([fibonacci_sphere(HULL_DIRECTIONS), np.eye(3), -np.eye(3)])
    keep = np.unique(np.argmax((vertices - centre) @ dirs.T, axis=0))
    return vertices[keep]


def _convex_hull_vertices(points: np.ndarray) -> np.ndarray:
    import trimesh

    if len(points) > HULL_MAX_POINTS:
        import warnings

        # The extreme points along the axes and diagonals are kept, so the hull keeps its extent.
        dirs = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1], [1, -1, 1], [-1, 1, 1], [1, 1, -1]], float)
        extremes = np.unique(np.concatenate([np.argmax(points @ dirs.T, 0), np.argmin(points @ dirs.T, 0)]))
        pick = np.random.default_rng(len(points)).choice(len(points), HULL_MAX_POINTS, replace=False)
        warnings.warn(f"collision hull of {len(points):,} vertices computed from {HULL_MAX_POINTS:,} of them",
                      stacklevel=2)
        points = points[np.union1d(pick, extremes)]
    try:
        hull = trimesh.convex.convex_hull(points)
        if len(hull.vertices) >= 4:
            return _fewer_hull_vertices(np.asarray(hull.vertices, dtype=np.float64))
    except Exception:
        pass
    lo, hi = points.min(0), points.max(0)
    hi = np.maximum(hi, lo + 1e-3)
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    return corners.astype(np.float64)


def build_collision_model(asset: ObjectAsset, collision: str = "convex_hull", cache_dir: Path | None = None) -> CollisionModel:
    mesh = meshio.read_mesh(asset.mesh_path)
    tm = _merged_trimesh(mesh)
    solid = _solid_for_mass(tm)
    volume = float(solid.volume)
    com = np.asarray(solid.center_mass, dtype=np.float64)
    # trimesh's inertia is for unit density about the centre of mass, in model axes.
    inertia_model = np.asarray(solid.moment_inertia, dtype=np.float64) * DENSITY
    moments, axes = np.linalg.eigh(inertia_model)
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    mass = max(volume * DENSITY, 1e-4)
    moments = np.maximum(moments, 1e-10)

    body_from_model = np.eye(4)
    body_from_model[:3, :3] = axes.T
    body_from_model[:3, 3] = -axes.T @ com

    def to_body(v: np.ndarray) -> np.ndarray:
        return v @ axes - com @ axes

    hull = to_body(_convex_hull_vertices(np.asarray(tm.vertices, dtype=np.float64)))
    parts: tuple = ()
    if collision == "decomposition":
        model_parts = convex_decomposition(asset.mesh_key, tm, cache_dir or default_collision_cache_dir())
        parts = tuple((to_body(v), f) for v, f in model_parts)
    elif collision != "convex_hull":
        raise ValueError(f"unknown collision mode {collision!r} (expected 'convex_hull' or 'decomposition')")
    extent = hull.max(0) - hull.min(0)
    return CollisionModel(
        mesh_key=asset.mesh_key,
        body_from_model=body_from_model,
        hull=hull,
        parts=parts,
        mass=mass,
        inertia=moments,
        min_thickness=float(extent.min()),
        radius=float(np.linalg.norm(hull, axis=1).max()),
    )


def convex_decomposition(mesh_key: str, tm, cache_dir: Path) -> list[tuple[np.ndarray, np.ndarray]]:
    """CoACD parts of a mesh in its model frame, computed once per mesh and cached on disk."""
    path = Path(cache_dir) / f"{mesh_key}.npz"
    meta = {"format": _DECOMPOSITION_FORMAT, "mesh_key": mesh_key, "coacd": _COACD_PARAMS}
    if path.exists():
        try:
            with np.load(path, allow_pickle=False) as z:
                if json.loads(str(z["meta"])) == meta:
                    return _split_parts(z["vertices"], z["faces"], z["nv"], z["nf"])
        except Exception:  # a corrupt or foreign file is recomputed and replaced
            pass
    import coacd

    coacd.set_log_level("error")
    result = coacd.run_coacd(
        coacd.Mesh(np.asarray(tm.vertices, dtype=np.float64), np.asarray(tm.faces, dtype=np.int32)),
        **_COACD_PARAMS,
    )
    parts = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int32)) for v, f in result]
    parts = [(v, f) for v, f in parts if len(v) >= 4 and len(f) >= 4]
    if not parts:  # degenerate decomposition: the hull is always a valid fallback
        hull = tm.convex_hull
        parts = [(np.asarray(hull.vertices, dtype=np.float64), np.asarray(hull.faces, dtype=np.int32))]
    buf = io.BytesIO()
    np.savez(
        buf,
        meta=np.array(json.dumps(meta)),
        vertices=np.concatenate([v for v, _ in parts]),
        faces=np.concatenate([f for _, f in parts]),
        nv=np.array([len(v) for v, _ in parts]),
        nf=np.array([len(f) for _, f in parts]),
    )
    atomic_write_bytes(path, buf.getvalue())
    # Return what was stored so a fresh computation and a cache hit give identical bits.
    with np.load(io.BytesIO(buf.getvalue()), allow_pickle=False) as z:
        return _split_parts(z["vertices"], z["faces"], z["nv"], z["nf"])


def _split_parts(vertices, faces, nv, nf) -> list[tuple[np.ndarray, np.ndarray]]:
    vs = np.split(np.asarray(vertices, dtype=np.float64), np.cumsum(nv)[:-1])
    fs = np.split(np.asarray(faces, dtype=np.int32), np.cumsum(nf)[:-1])
    return list(zip(vs, fs))


# --------------------------------------------------------------------------- small math


def _rot_z(yaw: float) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _quat_xyzw_to_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _matrix_to_quat_xyzw(R: np.ndarray) -> tuple[float, float, float, float]:
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        w, x, y, z = 0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2]) * 2
        w, x, y, z = (R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s
    elif R[1, 1] > R[2, 2]:
        s = math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2]) * 2
        w, x, y, z = (R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s
    else:
        s = math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1]) * 2
        w, x, y, z = (R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s
    q = np.array([x, y, z, w])
    q /= np.linalg.norm(q)
    return tuple(float(c) for c in q)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    # A normalised 4D Gaussian is uniform on the unit quaternions, i.e. uniform over rotations.
    for _ in range(16):
        q = rng.normal(size=4)
        n = np.linalg.norm(q)
        if n > 1e-6:
            return _quat_xyzw_to_matrix(q / n)
    return np.eye(3)


# --------------------------------------------------------------------------- the world


@dataclass
class _Body:
    index: int  # into the objects argument
    model: CollisionModel
    uid: int = -1
    frozen: bool = False


class _World:
    """One pybullet DIRECT client; every call names it explicitly."""

    def __init__(self, p, physics: Physics, tmpdir: Path):
        self.p = p
        self.phys = physics
        self.tmpdir = tmpdir
        self.cid = p.connect(p.DIRECT)
        if self.cid < 0:
            raise RuntimeError("pybullet: could not create a DIRECT client")
        self.colliders: list[int] = []
        self._shapes: dict[str, int] = {}

    def close(self) -> None:
        if self.p.isConnected(physicsClientId=self.cid):
            self.p.disconnect(physicsClientId=self.cid)

    def setup(self) -> None:
        p, c = self.p, self.cid
        p.resetSimulation(physicsClientId=c)
        p.setGravity(0, 0, -GRAVITY, physicsClientId=c)
        p.setTimeStep(self.phys.timestep, physicsClientId=c)
        p.setPhysicsEngineParameter(
            numSolverIterations=SOLVER_ITERATIONS,
            deterministicOverlappingPairs=1,
            physicsClientId=c,
        )

    def _surface(self, uid: int) -> None:
        self.p.changeDynamics(
            uid,
            -1,
            lateralFriction=self.phys.friction,
            restitution=self.phys.restitution,
            rollingFriction=ROLLING_FRICTION,
            spinningFriction=SPINNING_FRICTION,
            collisionMargin=COLLISION_MARGIN,
            physicsClientId=self.cid,
        )

    def add_collider(self, vertices_world: np.ndarray, faces: np.ndarray) -> None:
        p, c = self.p, self.cid
        for start in range(0, len(faces), _MAX_CHUNK_FACES):
            chunk = faces[start : start + _MAX_CHUNK_FACES]
            used, remap = np.unique(chunk, return_inverse=True)
            shape = p.createCollisionShape(
                p.GEOM_MESH,
                vertices=vertices_world[used].tolist(),
                indices=remap.astype(np.int64).ravel().tolist(),
                flags=p.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=c,
            )
            if shape < 0:
                raise RuntimeError("pybullet refused a scene collider mesh")
            uid = p.createMultiBody(baseMass=0.0, baseCollisionShapeIndex=shape, physicsClientId=c)
            self._surface(uid)
            self.colliders.append(uid)

    def _shape(self, model: CollisionModel) -> int:
        if model.mesh_key in self._shapes:
            return self._shapes[model.mesh_key]
        p, c = self.p, self.cid
        if model.parts:
            # createCollisionShapeArray takes meshes only as files: write the parts as OBJ with
            # round-trip float precision so the shapes are exactly the cached ones.
            files = []
            for k, (v, f) in enumerate(model.parts):
                fn = self.tmpdir / f"{len(self._shapes):04d}_{k:03d}.obj"
                lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
                lines += [f"f {a + 1} {b + 1} {d + 1}" for a, b, d in f.tolist()]
                fn.write_text("\n".join(lines) + "\n")
                files.append(str(fn))
            shape = p.createCollisionShapeArray([p.GEOM_MESH] * len(files), fileNames=files, physicsClientId=c)
        else:
            shape = p.createCollisionShape(p.GEOM_MESH, vertices=model.hull.tolist(), physicsClientId=c)
        if shape < 0:
            raise RuntimeError(f"pybullet refused the collision shape of mesh {model.mesh_key}")
        self._shapes[model.mesh_key] = shape
        return shape

    def add_object(self, body: _Body, pos: np.ndarray, R_world_body: np.ndarray) -> None:
        p, c, m = self.p, self.cid, body.model
        uid = p.createMultiBody(
            baseMass=m.mass,
            baseCollisionShapeIndex=self._shape(m),
            basePosition=pos.tolist(),
            baseOrientation=_matrix_to_quat_xyzw(R_world_body),
            physicsClientId=c,
        )
        self._surface(uid)
        # CCD (a swept sphere well inside the object; pybullet derives the motion threshold from
        # it) guards the centre against tunnelling. It does not stop edge-first impacts of thin
        # objects (measured: 15 of 40 jenga blocks dropped 0.5 m fell through a 2 cm table with
        # CCD alone); the speed-adaptive sub-stepping in _simulate does.
        p.changeDynamics(
            uid,
            -1,
            localInertiaDiagonal=m.inertia.tolist(),
            ccdSweptSphereRadius=0.2 * m.min_thickness,
            physicsClientId=c,
        )
        body.uid = uid
        body.frozen = False

    def remove(self, body: _Body) -> None:
        if body.uid >= 0:
            self.p.removeBody(body.uid, physicsClientId=self.cid)
        body.uid = -1

    def freeze(self, body: _Body) -> None:
        # Resting objects become static while others are re-dropped onto them, so a re-drop cannot
        # knock an already valid object off the stage and cascade.
        p, c = self.p, self.cid
        p.resetBaseVelocity(body.uid, [0, 0, 0], [0, 0, 0], physicsClientId=c)
        p.changeDynamics(body.uid, -1, mass=0.0, physicsClientId=c)
        body.frozen = True

    def pose(self, body: _Body) -> tuple[np.ndarray, np.ndarray]:
        pos, q = self.p.getBasePositionAndOrientation(body.uid, physicsClientId=self.cid)
        return np.asarray(pos, dtype=np.float64), np.asarray(q, dtype=np.float64)

    def world_from_model(self, body: _Body) -> np.ndarray:
        pos, q = self.pose(body)
        T = np.eye(4)
        T[:3, :3] = _quat_xyzw_to_matrix(q)
        T[:3, 3] = pos
        return T @ body.model.body_from_model

    def penetrates_collider(self, uid: int, tol: float) -> bool:
        for col in self.colliders:
            for pt in self.p.getClosestPoints(uid, col, 0.0, physicsClientId=self.cid):
                if pt[8] < -tol:
                    return True
        return False


# --------------------------------------------------------------------------- placement


def _check_stage(stage: Stage) -> None:
    if len(stage.polygon) < 3 or not stage.area > 0:
        raise ArrangeError(f"stage {stage.name!r}: polygon has no area ({len(stage.polygon)} vertices)")


def collider_region(stage: Stage, radius: float) -> np.ndarray:
    """[[xmin, ymin, zmin], [xmax, ymax, zmax]] of the scene geometry that objects of bounding
    radius ``radius`` dropped on ``stage`` can touch while they are simulated (see _COLLIDER_REACH)."""
    poly = np.asarray(stage.polygon, dtype=np.float64)
    reach = 2.0 * radius + _COLLIDER_REACH
    # Below this nothing is reached at all: a body entirely under the stage is dropped at once.
    lo = [*(poly.min(axis=0) - reach), stage.height - FALL_THROUGH_TOLERANCE - 2.0 * radius]
    hi = [*(poly.max(axis=0) + reach), np.inf]
    return np.array([lo, hi])


def box_meets_region(box: np.ndarray, region: np.ndarray) -> bool:
    """Whether the box [[min], [max]] meets the region's box (touching counts)."""
    return bool(np.all(box[1] >= region[0]) and np.all(box[0] <= region[1]))


def _world_box(vertices: np.ndarray, T: np.ndarray) -> np.ndarray:
    """A box containing the vertices moved by the affine ``T``: their model box's corners, moved."""
    lo, hi = vertices.min(axis=0).astype(np.float64), vertices.max(axis=0).astype(np.float64)
    corners = np.array(list(itertools.product(*zip(lo, hi))))
    moved = corners @ T[:3, :3].T + T[:3, 3]
    return np.stack([moved.min(axis=0), moved.max(axis=0)])


def faces_in_region(vertices: np.ndarray, faces: np.ndarray, region: np.ndarray) -> np.ndarray:
    """The faces whose bounding box meets the region's box (a superset of those that cross it)."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    if np.all(lo >= region[0]) and np.all(hi <= region[1]):
        return faces  # every vertex inside: every face meets it (the common case near a stage)
    if not box_meets_region(np.stack([lo, hi]), region):
        return faces[:0]
    tri = vertices[faces]
    keep = np.all(tri.max(axis=1) >= region[0], axis=1) & np.all(tri.min(axis=1) <= region[1], axis=1)
    return faces[keep]


def _aabb(offsets: np.ndarray, pos: np.ndarray) -> np.ndarray:
    return np.stack([offsets.min(0) + pos, offsets.max(0) + pos])


def _overlaps(a: np.ndarray, b: np.ndarray, gap: float) -> bool:
    return bool(np.all(a[0] < b[1] + gap) and np.all(b[0] < a[1] + gap))


STAND_GAP = 0.001  # metres between a standing object's lowest point and the stage: no start in contact


def _start_height(arrangements: Arrangements, rng: np.random.Generator) -> float:
    """Height of an object's lowest point above the stage at the start. A standing object draws no
    number, so that its other draws are the same whatever drop_height says."""
    if arrangements.placement == "stand":
        return STAND_GAP
    lo_drop, hi_drop = arrangements.drop_height
    return float(rng.uniform(lo_drop, hi_drop))


def _initial_pose(
    body: _Body,
    stage: Stage,
    arrangements: Arrangements,
    orientation: str,
    rng: np.random.Generator,
    occupied: list[np.ndarray],
    stack: bool = True,
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Sample a start pose; returns (COM position, R_world_body, world AABB), or None when no free
    spot was found and ``stack`` is off (else it starts above what is in the way)."""
    m = body.model
    if orientation == "canonical":
        R_world_model = _rot_z(float(rng.uniform(0.0, 2.0 * math.pi)))
    elif orientation == "random":
        R_world_model = _random_rotation(rng)
    else:
        raise ValueError(f"unknown orientation {orientation!r} (expected 'canonical' or 'random')")
    R_world_body = R_world_model @ m.body_from_model[:3, :3].T
    offsets = m.hull @ R_world_body.T
    footprint = float(np.linalg.norm(offsets[:, :2], axis=1).max())
    z = stage.height - float(offsets[:, 2].min()) + _start_height(arrangements, rng)

    pos = None
    for _ in range(_PLACEMENT_TRIES):
        xy = stage.sample_point(rng, margin=0.5 * footprint)
        cand = np.array([xy[0], xy[1], z])
        box = _aabb(offsets, cand)
        if not any(_overlaps(box, o, _START_GAP) for o in occupied):
            return cand, R_world_body, box
        if pos is None:
            pos = cand
    if not stack:
        return None
    # No free spot at this height: stack above whatever is in the way. Each lift clears one box
    # for good (z only grows), so this ends after at most len(occupied) lifts.
    box = _aabb(offsets, pos)
    for _ in range(len(occupied) + 1):
        hits = [o for o in occupied if _overlaps(box, o, _START_GAP)]
        if not hits:
            break
        lift = max(o[1, 2] for o in hits) + _START_GAP - box[0, 2]
        pos = pos + np.array([0.0, 0.0, lift])
        box = _aabb(offsets, pos)
    return pos, R_world_body, box


def _start(world, bodies: list[_Body], stage: Stage, arrangements: Arrangements, orientation: str,
           rng: np.random.Generator, occupied: dict[int, np.ndarray], first_unstacked: int) -> list[_Body]:
    """Add ``bodies`` to the world at their start poses, recording their boxes in ``occupied``;
    the ones from index ``first_unstacked`` on that find no free spot are left out. -> the added."""
    added = []
    for b in bodies:
        start = _initial_pose(b, stage, arrangements, orientation, rng, list(occupied.values()),
                              stack=b.index < first_unstacked)
        if start is None:
            continue
        pos, R, box = start
        world.add_object(b, pos, R)
        occupied[b.index] = box
        added.append(b)
    return added


# --------------------------------------------------------------------------- simulation


def _simulate(world: _World, bodies: list[_Body], stage: Stage) -> tuple[int, bool, dict[int, str]]:
    """Step until all dynamic bodies rest for hold_time or max_time passes.

    Returns (steps, settled, {index: reason} of bodies lost on the way: fallen or NaN).
    """
    p, c, phys = world.p, world.cid, world.phys
    dt = phys.timestep
    max_steps = max(1, math.ceil(phys.max_time / dt - 1e-9))
    hold_steps = max(1, math.ceil(phys.hold_time / dt - 1e-9))
    # Mean speeds over the hold window, as the distance and angle the window may span.
    reach = (phys.linear_threshold * hold_steps * dt, phys.angular_threshold * hold_steps * dt)
    active = [b for b in bodies if b.uid >= 0 and not b.frozen]
    calm: dict[int, _CalmWindow] = {}
    lost: dict[int, str] = {}
    if not active:
        return 0, True, lost
    limit = {b.index: min(_MAX_SUBSTEP_TRAVEL, 0.4 * b.model.min_thickness) for b in active}
    substeps = 0
    want = 1
    check_every = max(1, round(_LEFT_STAGE_CHECK / dt))
    give_up = max(1, math.ceil(_LEFT_STAGE_GIVE_UP / dt / check_every))
    outside = {b.index: 0 for b in active}
    try:
        for step in range(1, max_steps + 1):
            if want != substeps:
                substeps = want
                p.setPhysicsEngineParameter(numSubSteps=substeps, physicsClientId=c)
            p.stepSimulation(physicsClientId=c)
            all_calm, want = _after_step(world, active, calm, lost, limit, hold_steps, reach, dt, stage)
            if step % check_every == 0 and active:
                xy = np.array([p.getBasePositionAndOrientation(b.uid, physicsClientId=c)[0][:2] for b in active])
                for b, inside in zip(list(active), stage.contains(xy)):
                    outside[b.index] = 0 if inside else outside[b.index] + 1
                    if outside[b.index] >= give_up:
                        lost[b.index] = "left_stage"
                        world.remove(b)
                        active.remove(b)
                all_calm = all_calm and all(calm[b.index].steps >= hold_steps for b in active)
            if all_calm:
                return step, True, lost
    finally:
        if substeps != 1:
            p.setPhysicsEngineParameter(numSubSteps=1, physicsClientId=c)
    return max_steps, False, lost


@dataclass
class _CalmWindow:
    """A body's pose when its current calm window began, and the steps it has stayed near it."""

    pos: tuple[float, float, float]
    q: tuple[float, float, float, float]
    steps: int = 0


def quat_angle(q0, q1) -> float:
    """Angle (rad) of the rotation between two orientations given as unit quaternions (x, y, z, w)."""
    d = abs(q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3])
    return 2.0 * math.acos(min(1.0, d))


def _stays_calm(window: _CalmWindow, pos, q, reach: tuple[float, float]) -> bool:
    """Whether a body at (pos, q) is still within ``reach`` = (metres, radians) of its window start.

    Calm is judged on where a body is, not on its instantaneous velocity: objects resting in a pile
    or on a triangle mesh jitter (measured on the demo's rooms: angular speed spikes of 0.2-1.4
    rad/s while the centre moves 0.1-0.4 mm in 4 s), which a velocity test never sees as calm.
    """
    dx, dy, dz = pos[0] - window.pos[0], pos[1] - window.pos[1], pos[2] - window.pos[2]
    return dx * dx + dy * dy + dz * dz <= reach[0] * reach[0] and quat_angle(window.q, q) <= reach[1]


def _after_step(world, active, calm, lost, limit, hold_steps, reach, dt, stage) -> tuple[bool, int]:
    """Update calm windows and drop lost bodies; returns (all calm, sub-steps for the next step)."""
    p, c = world.p, world.cid
    all_calm = True
    want = 1
    for b in list(active):
        pos, q = p.getBasePositionAndOrientation(b.uid, physicsClientId=c)
        v, w = p.getBaseVelocity(b.uid, physicsClientId=c)
        # Entirely below the stage: it fell off or through; nothing can bring it back, so stop
        # simulating it instead of waiting for it to land somewhere far below.
        if not all(map(math.isfinite, pos + v + w)):
            lost[b.index] = "nan"
        elif pos[2] + b.model.radius < stage.height - FALL_THROUGH_TOLERANCE:
            lost[b.index] = "fell_through" if bool(stage.contains(pos[:2])) else "fell_off"
        if b.index in lost:
            world.remove(b)
            active.remove(b)
            continue
        window = calm.get(b.index)
        if window is not None and _stays_calm(window, pos, q, reach):
            window.steps += 1
        else:
            window = calm[b.index] = _CalmWindow(pos, q)
        if window.steps < hold_steps:
            all_calm = False
        # Fastest point: centre speed + spin * radius, plus what gravity adds in one step.
        speed = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        spin = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        travel = (speed + spin * b.model.radius + GRAVITY * dt) * dt
        want = max(want, min(_MAX_SUBSTEPS, math.ceil(travel / limit[b.index])))
    return all_calm, want


def _validate(world: _World, bodies: list[_Body], stage: Stage) -> dict[int, str]:
    """{index: reason} of dynamic bodies that are invalid at rest."""
    p, c, tol = world.p, world.cid, world.phys.penetration_tolerance
    p.performCollisionDetection(physicsClientId=c)
    by_uid = {b.uid: b for b in bodies if b.uid >= 0}
    invalid: dict[int, str] = {}
    for b in bodies:
        if b.uid < 0 or b.frozen:
            continue
        pos, q = world.pose(b)
        if not (np.isfinite(pos).all() and np.isfinite(q).all()):
            invalid[b.index] = "nan"
            continue
        R = _quat_xyzw_to_matrix(q)
        lowest = float((b.model.hull @ R.T)[:, 2].min() + pos[2])
        over = bool(stage.contains(pos[:2]))
        if lowest < stage.height - FALL_THROUGH_TOLERANCE:
            invalid[b.index] = "fell_through" if over else "fell_off"
        elif not over:
            invalid[b.index] = "left_stage"
        elif world.penetrates_collider(b.uid, tol):
            invalid[b.index] = "penetration"
    # Object-object penetration: blame the upper one (the dynamic one against a frozen body),
    # since removing it is what resolves a pile.
    for b in bodies:
        if b.uid < 0 or b.frozen or b.index in invalid:
            continue
        for pt in p.getContactPoints(bodyA=b.uid, physicsClientId=c):
            other = by_uid.get(pt[2])
            if other is None or pt[8] >= -tol or other.index in invalid:
                continue
            if other.frozen or world.pose(b)[0][2] >= world.pose(other)[0][2]:
                invalid[b.index] = "penetration"
            else:
                invalid[other.index] = "penetration"
            if b.index in invalid:
                break
    return invalid


def _add_colliders(world: _World, scene: SceneDesc, region: np.ndarray) -> None:
    """The scene's collider meshes, only their faces inside ``region``, as static bodies."""
    for inst in scene.collider_meshes():
        mesh = meshio.read_mesh(inst.mesh_path)
        T = inst.matrix
        if not box_meets_region(_world_box(mesh.vertices, T), region):
            continue  # most of a room: skip its transform and per-face test
        # Colliders are placed in world coordinates directly: exact for any affine pose
        # (including scale), and static bodies never move.
        v = mesh.vertices.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        faces = faces_in_region(v, mesh.faces, region)
        if len(faces):
            world.add_collider(v, faces)


def arrange(
    scene: SceneDesc,
    stage: Stage,
    objects: list[ObjectAsset],
    arrangements: Arrangements,
    orientation: Literal["canonical", "random"],
    rng: np.random.Generator,
    *,
    shapes: ShapeCache | None = None,
    collision_cache: Path | None = None,
    unstacked: int = 0,
) -> ArrangeResult:
    """Drop ``objects`` (one entry per instance) onto ``stage`` of ``scene`` and let them settle.

    The last ``unstacked`` objects (distractors standing round the objects) are left out, counted
    as removed for "no_room", when no free spot is found for them, instead of starting stacked on
    the others as the rest do.

    ``shapes`` optionally reuses collision models across calls; ``collision_cache`` is where convex
    decompositions are stored (default: :func:`default_collision_cache_dir`).
    Raises :class:`ArrangeError` (a ``ValueError``) when objects were given but none could be kept.
    """
    # pybullet prints "pybullet build time: <date>" to stderr on its first import: a line per
    # worker process that tells a user nothing.
    p = processes.import_quietly("pybullet", "pybullet build time:")

    _check_stage(stage)
    phys = arrangements.physics
    if orientation not in ("canonical", "random"):
        raise ValueError(f"unknown orientation {orientation!r} (expected 'canonical' or 'random')")
    if not objects:
        return ArrangeResult(placed=[], removed=0, redropped=0, settled=True, sim_seconds=0.0)
    shapes = shapes if shapes is not None else ShapeCache()
    bodies = [_Body(i, shapes.get(a, phys.collision, collision_cache)) for i, a in enumerate(objects)]

    with tempfile.TemporaryDirectory(prefix="specsynth-physics-") as tmp:
        world = _World(p, phys, Path(tmp))
        try:
            world.setup()
            _add_colliders(world, scene, collider_region(stage, max(b.model.radius for b in bodies)))

            redrops = [0] * len(bodies)
            removed = redropped = steps_total = 0
            settled_all = True
            reasons: dict[str, int] = {}
            to_drop = list(bodies)
            occupied: dict[int, np.ndarray] = {}
            # Each round re-drops only objects with redrops left, so rounds <= max_redrops + 1.
            while to_drop:
                placed_now = _start(world, to_drop, stage, arrangements, orientation, rng, occupied,
                                    first_unstacked=len(bodies) - unstacked)
                if len(placed_now) < len(to_drop):
                    reasons["no_room"] = reasons.get("no_room", 0) + len(to_drop) - len(placed_now)
                    removed += len(to_drop) - len(placed_now)
                to_drop = placed_now
                if not to_drop:
                    break
                steps, settled, lost = _simulate(world, to_drop, stage)
                steps_total += steps
                settled_all &= settled
                invalid = {**_validate(world, to_drop, stage), **lost}
                next_round = []
                for b in to_drop:
                    if b.index not in invalid:
                        world.freeze(b)
                        continue
                    reasons[invalid[b.index]] = reasons.get(invalid[b.index], 0) + 1
                    world.remove(b)
                    if phys.on_invalid == "redrop" and redrops[b.index] < phys.max_redrops:
                        redrops[b.index] += 1
                        redropped += 1
                        next_round.append(b)
                    else:
                        removed += 1
                # Start boxes of the kept objects become their resting boxes: re-drops avoid them.
                occupied = {}
                for b in bodies:
                    if b.uid >= 0 and b.frozen:
                        pos, q = world.pose(b)
                        occupied[b.index] = _aabb(b.model.hull @ _quat_xyzw_to_matrix(q).T, pos)
                to_drop = next_round

            placed = [(b.index, world.world_from_model(b)) for b in bodies if b.uid >= 0]
        finally:
            world.close()

    if not placed:
        raise ArrangeError(
            f"stage {stage.name!r} of scene {scene.name!r} (area {stage.area:.4g} m^2, height "
            f"{stage.height:.3f} m): none of {len(objects)} objects could be kept after "
            f"{redropped} re-drops; the stage is too small for them or nothing supports it"
        )
    return ArrangeResult(
        placed=placed,
        removed=removed,
        redropped=redropped,
        settled=settled_all,
        sim_seconds=steps_total * phys.timestep,
        invalid_reasons=reasons,
    )

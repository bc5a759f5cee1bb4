"""An exact OpenCV pinhole for Mitsuba: a Python sensor tracing ``K^-1 [u, v, 1]``.

Mitsuba's ``perspective`` sensor has square pixels and no skew, so ``fy != fx`` cannot be
expressed with it. This sensor takes the intrinsics themselves (``fx``, ``fy``, ``cx``, ``cy``,
``skew``; OpenCV convention, pixel centres at integer coordinates) and is otherwise a drop-in
replacement: same ``to_world`` frame (Mitsuba camera: looks down +Z, +X to the image left, +Y up,
i.e. ``opencv_to_mitsuba_c2w``), same ``near_clip`` / ``far_clip`` handling, same film and
sampler children, same traversable ``to_world`` (an opaque JIT variable: moving the camera
through ``mi.traverse(sensor)["to_world"]`` re-uses the compiled kernels).

Film position (x, y) in pixels (pixel i spans [i, i + 1]) is the OpenCV point
(u, v) = (x - 0.5, y - 0.5); its OpenCV camera-space direction is

    K^-1 [u, v, 1] = [(u - cx) / fx - skew (v - cy) / (fx fy), (v - cy) / fy, 1]

and the Mitsuba local direction flips X and Y. Both are affine in the sample, so the sensor
stores five opaque coefficients (computed in double precision) and evaluates

    local = (ax * sx + axy * sy + bx, ay * sy + by, 1)

for the sample (sx, sy) in [0, 1]^2 relative to the film's crop window.

Like ``textures.py``, the class must derive from the *active variant's* ``mi.Sensor``, so it is
made (and registered with Mitsuba's plugin registry) after ``mi.set_variant``.
"""

from __future__ import annotations

import numpy as np

PINHOLE = "specsynth_pinhole"


def local_coefficients(
    fx: float, fy: float, cx: float, cy: float, skew: float, crop_offset: tuple[int, int], crop_size: tuple[int, int]
) -> tuple[float, float, float, float, float]:
    """(ax, axy, bx, ay, by): Mitsuba-local direction x = ax sx + axy sy + bx, y = ay sy + by
    (z = 1) for the crop-relative film sample (sx, sy). Pure numbers (unit tested)."""
    ox, oy = float(crop_offset[0]), float(crop_offset[1])
    w, h = float(crop_size[0]), float(crop_size[1])
    # OpenCV pixel coordinates of the sample: u = ox + sx w - 0.5, v = oy + sy h - 0.5
    # y_cv = (v - cy) / fy ;  x_cv = (u - cx) / fx - skew / fx * y_cv ;  Mitsuba local = (-x_cv, -y_cv)
    ycv_s, ycv_0 = h / fy, (oy - 0.5 - cy) / fy
    xcv_sx, xcv_0 = w / fx, (ox - 0.5 - cx) / fx
    k = skew / fx
    return (-xcv_sx, k * ycv_s, -(xcv_0 - k * ycv_0), -ycv_s, -ycv_0)


def _check_rigid(to_world) -> None:
    """Like ``perspective``: no scale in the camera-to-world transform (it would scale rays)."""
    R = np.asarray(to_world.matrix, dtype=np.float64).reshape(4, 4)[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-4):
        raise ValueError(f"{PINHOLE}: to_world must be rigid (no scale or shear)")


def register_pinhole_sensor(mi) -> None:
    import drjit as dr

    class PinholeKSensor(mi.Sensor):
        """Pinhole with an arbitrary upper-triangular K (see the module docstring)."""

        def __init__(self, props):
            super().__init__(props)  # takes the film and sampler children
            self.fx = float(props["fx"])
            self.fy = float(props["fy"])
            self.cx = float(props["cx"])
            self.cy = float(props["cy"])
            self.skew = float(props.get("skew", 0.0))
            self.near_clip = float(props.get("near_clip", 1e-2))
            self.far_clip = float(props.get("far_clip", 1e4))
            if self.fx <= 0 or self.fy <= 0:
                raise ValueError(f"{PINHOLE}: fx and fy must be positive (got {self.fx}, {self.fy})")
            if not 0.0 < self.near_clip < self.far_clip:
                raise ValueError(f"{PINHOLE}: need 0 < near_clip < far_clip (got {self.near_clip}, {self.far_clip})")
            to_world = props.get("to_world", mi.ScalarTransform4f())  # a double-precision scalar transform
            self.to_world = mi.Transform4f(np.asarray(to_world.matrix, dtype=np.float32).reshape(4, 4))
            self.m_needs_sample_3 = False  # no aperture: the sampler draws what it draws for perspective
            self._update()
            _check_rigid(self.to_world)

        # -------------------------------------------------------------- parameters

        def _update(self) -> None:
            film = self.film()
            off, size = film.crop_offset(), film.crop_size()
            ax, axy, bx, ay, by = local_coefficients(
                self.fx, self.fy, self.cx, self.cy, self.skew, (off[0], off[1]), (size[0], size[1])
            )
            self._coef = (mi.Float(ax), mi.Float(axy), mi.Float(bx), mi.Float(ay), mi.Float(by))
            # one pixel step along film x / y, in local directions at z = 1 (ray differentials)
            self._dx = mi.Vector3f(-1.0 / self.fx, 0.0, 0.0)
            self._dy = mi.Vector3f(self.skew / (self.fx * self.fy), -1.0 / self.fy, 0.0)
            self._near = mi.Float(self.near_clip)
            self._far = mi.Float(self.far_clip)
            # Opaque: kernel inputs rather than literals, so new values never recompile a kernel.
            dr.make_opaque(self.to_world, self._coef, self._dx, self._dy, self._near, self._far)
            self.m_to_world = self.to_world  # mirrored for C++ callers of world_transform()

        def traverse(self, callback):
            callback.put("to_world", self.to_world, mi.ParamFlags.NonDifferentiable)
            callback.put("film", self.film(), mi.ParamFlags.NonDifferentiable)
            callback.put("sampler", self.sampler(), mi.ParamFlags.NonDifferentiable)

        def parameters_changed(self, keys):
            # _update() first: it makes to_world opaque *before* _check_rigid reads it back (reading
            # a matrix of literals into numpy compiles a kernel with the values baked in: one per pose)
            self._update()
            if not keys or "to_world" in keys:
                _check_rigid(self.to_world)

        # -------------------------------------------------------------- sampling

        def _local(self, position_sample):
            ax, axy, bx, ay, by = self._coef
            return mi.Vector3f(
                dr.fma(ax, position_sample.x, dr.fma(axy, position_sample.y, bx)),
                dr.fma(ay, position_sample.y, by),
                1.0,
            )

        def _ray(self, time, wavelength_sample, position_sample, active):
            wavelengths, weight = self.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active)
            p = self._local(position_sample)  # on the plane z = 1
            d = dr.normalize(p)
            inv_z = dr.rcp(d.z)
            near_t, far_t = self._near * inv_z, self._far * inv_z
            dw = self.to_world @ d
            o = self.to_world.translation() + dw * near_t
            ray = mi.RayDifferential3f(mi.Ray3f(o, dw, far_t - near_t, time, wavelengths))
            return ray, p, weight

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            ray, _, weight = self._ray(time, sample1, sample2, active)
            return mi.Ray3f(ray), weight

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            ray, p, weight = self._ray(time, sample1, sample2, active)
            ray.o_x = ray.o
            ray.o_y = ray.o
            ray.d_x = self.to_world @ dr.normalize(p + self._dx)
            ray.d_y = self.to_world @ dr.normalize(p + self._dy)
            ray.has_differentials = True
            return ray, weight

        def bbox(self):
            t = np.asarray(self.to_world.translation(), dtype=np.float64).reshape(3)
            p = mi.ScalarPoint3f(*map(float, t))
            return mi.ScalarBoundingBox3f(p, p)

        def to_string(self):
            return (
                f"PinholeKSensor[fx={self.fx}, fy={self.fy}, cx={self.cx}, cy={self.cy}, skew={self.skew}, "
                f"near_clip={self.near_clip}, far_clip={self.far_clip}, film={self.film()}]"
            )

    mi.register_sensor(PINHOLE, lambda props: PinholeKSensor(props))


def _bench(width: int = 320, height: int = 240, spp: int = 16, views: int = 6, threads: int = 1) -> None:
    """Seconds per view, built-in ``perspective`` vs this sensor, through MitsubaBackend:
    ``python -c "from backends.mitsuba.sensor import _bench; _bench()"``. Floor + two balls + area light, a new pose per view
    (warm kernels: the first view of each sensor is not timed), the sensors interleaved so that
    a neighbour's load hits both alike. Prints wall and CPU (process) seconds, medians."""
    import tempfile
    import time
    from pathlib import Path

    import trimesh

    from specsynth.cameras import look_at
    from specsynth.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, as_tuple
    from specsynth.meshio import MeshData, write_mesh
    from specsynth.spec import QualityPreset

    from .backend import MitsubaBackend

    tmp = Path(tempfile.mkdtemp())

    def mesh(name, tm):
        p = tmp / f"{name}.ply"
        write_mesh(p, MeshData(vertices=tm.vertices.astype(np.float32), faces=tm.faces.astype(np.int32),
                               normals=tm.vertex_normals.astype(np.float32)))
        return str(p)

    def pose(t, s=1.0):
        T = np.diag([s, s, s, 1.0])
        T[:3, 3] = t
        return as_tuple(T)

    floor = mesh("floor", trimesh.creation.box(extents=[4.0, 4.0, 0.02]))
    ball = mesh("ball", trimesh.creation.icosphere(subdivisions=4, radius=0.3))
    scene = RenderScene(
        meshes=(
            MeshInstance("floor", floor, "floor", pose((0, 0, -0.01)), MaterialIR(specular=0.0, metallic=0.0, roughness=1.0)),
            MeshInstance("b1", ball, "ball", pose((0.2, 0, 0.3)), MaterialIR(base_color=(0.8, 0.2, 0.2), roughness=0.3)),
            MeshInstance("b2", ball, "ball", pose((-0.5, 0.4, 0.3)), MaterialIR(base_color=(0.2, 0.6, 0.8))),
        ),
        lights=(LightIR(kind="area", pose=pose((0, 0, 2.0)), power=80.0, size=(0.5, 0.5)),),
    )
    quality = QualityPreset(aa=spp, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)
    f = 0.9 * width
    configs = {  # name: (fy, use the K sensor); one backend each, so each keeps its sensor
        "perspective, fy = fx": (f, False),
        f"{PINHOLE}, fy = fx": (f, True),
        f"{PINHOLE}, fy = 1.1 fx": (1.1 * f, True),
    }
    backends = {}
    for name, (_, k_sensor) in configs.items():
        b = backends[name] = MitsubaBackend({"variant": "auto"}, threads=threads)
        b._use_k_sensor = lambda sset, k=k_sensor: k  # the benchmark forces the choice
        b.load(scene)
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in configs}
    for i in range(views + 1):
        a = 2 * np.pi * i / (views + 1)
        R, t = look_at(np.array([2.0 * np.cos(a), 2.0 * np.sin(a), 1.2]), np.array([0.0, 0.0, 0.2]))
        for name, (fy, k_sensor) in configs.items():
            K = np.array([[f, 0, (width - 1) / 2 + 3.3], [0, fy, (height - 1) / 2 - 2.1], [0, 0, 1]])
            cam = CameraIR(K=as_tuple(K), width=width, height=height, R_w2c=as_tuple(R), t_w2c=as_tuple(t))
            w0, c0 = time.perf_counter(), time.process_time()
            r = backends[name].render(cam, quality, seed=i)
            w1, c1 = time.perf_counter(), time.process_time()
            assert r.stats["sensor"] == (PINHOLE if k_sensor else "perspective")
            if i > 0:  # view 0 builds the sensor and compiles
                times[name].append((w1 - w0, c1 - c0))
    variant = next(iter(backends.values())).variant
    print(f"{variant}, {width}x{height}, {spp} spp, threads={threads}, {views} timed views each (medians):")
    base = float(np.median([c for _, c in times["perspective, fy = fx"]]))
    for name, tt in times.items():
        wall, cpu = np.median([w for w, _ in tt]), np.median([c for _, c in tt])
        print(f"  {name:30s} wall {wall:.3f} s  cpu {cpu:.3f} s  ({100 * (cpu / base - 1):+.1f} % cpu)")
    for b in backends.values():
        b.close()

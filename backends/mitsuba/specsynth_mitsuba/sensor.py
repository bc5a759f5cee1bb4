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

With ``aperture_radius`` > 0 it is a thin lens: the ray leaves a point of the pupil disk (the
third sample, mapped concentrically) towards the point the pinhole ray meets at ``focus_distance``
along the axis, so that plane stays sharp. Both are traversable and opaque (a new focus per image
compiles nothing); whether there is a lens at all is fixed when the sensor is made. Likewise
``motion_translation`` / ``motion_rotation`` (Mitsuba-local, from shutter open to close): with
``shutter_close`` > 0 the ray's time t in [0, 1] moves and turns the camera by (t - 1/2) of them
about its mid-exposure pose (``specsynth.model.conventions.c2w_during_exposure``).

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
            radius = float(props.get("aperture_radius", 0.0))
            self._lens = radius > 0
            # drjit values (traverse can only hand out those), set here once and updated in place
            self._aperture = mi.Float(radius)
            self._focus = mi.Float(float(props.get("focus_distance", 1.0)))
            self._moving = float(props.get("shutter_close", 0.0)) > 0
            self._travel = mi.Vector3f(*(float(props.get(f"motion_t{a}", 0.0)) for a in "xyz"))
            self._turn = mi.Vector3f(*(float(props.get(f"motion_r{a}", 0.0)) for a in "xyz"))
            # without a lens the sampler draws what it draws for perspective
            self.m_needs_sample_3 = self._lens
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
            dr.make_opaque(self.to_world, self._coef, self._dx, self._dy, self._near, self._far, self._aperture, self._focus,
                           self._travel, self._turn)
            self.m_to_world = self.to_world  # mirrored for C++ callers of world_transform()

        def traverse(self, callback):
            callback.put("to_world", self.to_world, mi.ParamFlags.NonDifferentiable)
            if self._lens:
                callback.put("aperture_radius", self._aperture, mi.ParamFlags.NonDifferentiable)
                callback.put("focus_distance", self._focus, mi.ParamFlags.NonDifferentiable)
            if self._moving:
                callback.put("motion_translation", self._travel, mi.ParamFlags.NonDifferentiable)
                callback.put("motion_rotation", self._turn, mi.ParamFlags.NonDifferentiable)
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

        def _ray(self, time, wavelength_sample, position_sample, active, aperture_sample=None):
            wavelengths, weight = self.sample_wavelengths(dr.zeros(mi.SurfaceInteraction3f), wavelength_sample, active)
            p = self._local(position_sample)  # on the plane z = 1
            if self._lens:
                disk = mi.warp.square_to_uniform_disk_concentric(aperture_sample) * self._aperture
                pupil = mi.Vector3f(disk.x, disk.y, 0.0)
                d = dr.normalize(mi.Vector3f(p * self._focus - pupil))
            else:
                pupil = mi.Vector3f(0.0)
                d = dr.normalize(p)
            if self._moving:  # the camera's own motion over the exposure, in its local frame
                s = time - 0.5
                pupil = self._turned(pupil, s) + self._travel * s
                d = self._turned(d, s)
            start = self.to_world @ mi.Point3f(pupil)
            inv_z = dr.rcp(d.z)
            near_t, far_t = self._near * inv_z, self._far * inv_z
            dw = self.to_world @ d
            o = start + dw * near_t
            ray = mi.RayDifferential3f(mi.Ray3f(o, dw, far_t - near_t, time, wavelengths))
            return ray, p, weight

        def _turned(self, v, s):
            """v rotated by the rotation vector s * motion_rotation (Rodrigues)."""
            r = self._turn * s
            theta = dr.norm(r)
            k = r / dr.maximum(theta, 1e-12)
            c, sn = dr.cos(theta), dr.sin(theta)
            return v * c + dr.cross(k, v) * sn + k * dr.dot(k, v) * (1.0 - c)

        def sample_ray(self, time, sample1, sample2, sample3, active=True):
            ray, _, weight = self._ray(time, sample1, sample2, active, sample3)
            return mi.Ray3f(ray), weight

        def sample_ray_differential(self, time, sample1, sample2, sample3, active=True):
            ray, p, weight = self._ray(time, sample1, sample2, active, sample3)
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

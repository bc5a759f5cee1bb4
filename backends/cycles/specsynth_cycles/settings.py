"""Paper preset -> Cycles settings, and OpenCV intrinsics -> Blender camera parameters.

Pure functions without bpy so that the mapping can be unit-tested (and documented) without a renderer.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from typing import Any, Iterator

import numpy as np

from specsynth.model.ir import CameraIR
from specsynth.spec.models import QualityPreset

from .options import CyclesOptions


def coerce_options(options: Any) -> CyclesOptions:
    """Accept the spec's ``CyclesOptions``, a plain dict or None."""
    if options is None:
        return CyclesOptions()
    if isinstance(options, CyclesOptions):
        return options
    return CyclesOptions.model_validate({**dict(options), "name": "cycles"})


def resolve_threads(options: CyclesOptions, threads: int) -> int:
    """A fixed thread count; affinity first because containers often pin fewer cores than cpu_count."""
    n = options.threads or threads
    if n > 0:
        return n
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


@contextmanager
def tbb_sized_to(threads: int) -> Iterator[None]:
    """Import bpy inside this so that Blender's TBB pool has ``threads`` threads, not one per core.

    Blender creates its TBB pool when bpy is imported, sized from the process's CPU affinity, and
    ``render.threads`` does not shrink it. With one render thread on a 2-core machine the idle TBB
    worker spins in ``sched_yield`` whenever Cycles runs a parallel step (BVH build, background
    importance map): measured 15 s of system CPU in a 19 s build, taken from the other worker
    when two run side by side. Narrowing the affinity for the import only sizes that pool; the
    mask is restored at once, so the render threads may still run on any core.

    TBB reads the mask of the process's main thread, not of the importing thread: a Dask worker
    imports bpy on its job thread, and narrowing that thread alone left the pool at one thread
    per core (1.84 cores used by a 1-thread render loop). Both threads are narrowed. A thread
    started meanwhile would keep the narrowed mask; the import takes about a second.
    """
    try:
        full = os.sched_getaffinity(0)
    except (AttributeError, OSError):  # pragma: no cover - non-Linux: nothing to narrow
        yield
        return
    if not 0 < threads < len(full):
        yield
        return
    tids = {0, os.getpid()}  # this thread, and the main thread (whose id is the pid)
    saved = {t: os.sched_getaffinity(t) for t in tids}
    for t in tids:
        os.sched_setaffinity(t, sorted(full)[:threads])
    try:
        yield
    finally:
        for t, mask in saved.items():
            os.sched_setaffinity(t, mask)


def preset_samples(q: QualityPreset) -> int:
    """Camera samples per pixel for a paper preset: max(AA, diffuse rays, specular rays).

    A unidirectional path tracer traces one diffuse and one specular continuation per camera sample,
    so N samples give N first-bounce rays of each kind per pixel. Arnold's AA x D-rays (324 / 5625) would
    cost ~80x / ~1400x the low preset, whereas the paper's own times are 15 / 120 / 720 s (1 : 8 : 48);
    max() gives 1 / 36 / 225 spp, measured 1 : ~10 : ~56 here: the paper's cost ratio and at least as
    many camera rays and first-bounce rays per pixel as Arnold spends per camera ray.
    """
    return q.samples


@dataclass(frozen=True)
class PathSettings:
    samples: int
    max_bounces: int
    diffuse_bounces: int
    glossy_bounces: int
    transmission_bounces: int
    glossy_skipped: bool
    transmission_skipped: bool
    denoise: bool
    denoise_prefilter: str
    denoise_quality: str
    adaptive_threshold: float | None
    clamp_indirect: float
    guiding: bool = False

    def stats(self) -> dict:
        d = asdict(self)
        d["bounces"] = {k: d.pop(f"{k}_bounces") for k in ("max", "diffuse", "glossy", "transmission")}
        return d


def path_settings(
    q: QualityPreset, options: CyclesOptions, *, has_glossy: bool, has_transmission: bool, clamp: float | None
) -> PathSettings:
    """Light-path budget: the preset's depths, minus the kinds of bounce the scene cannot use."""
    # Glass needs one transmission bounce to enter and one to leave a solid, so the specular depth
    # (1 at low) would render it black: give transmission the total depth budget instead.
    return PathSettings(
        samples=options.samples or preset_samples(q),
        max_bounces=q.max_depth,
        diffuse_bounces=min(q.diffuse_depth, q.max_depth),
        glossy_bounces=min(q.specular_depth, q.max_depth) if has_glossy else 0,
        transmission_bounces=q.max_depth if has_transmission else 0,
        glossy_skipped=not has_glossy,
        transmission_skipped=not has_transmission,
        denoise=options.denoise,
        denoise_prefilter=options.denoise_prefilter.upper(),
        denoise_quality=options.denoise_quality.upper(),
        adaptive_threshold=options.adaptive_threshold,
        # 0 disables clamping; Blender's default of 10 biases energy, so only clamp when asked to.
        clamp_indirect=float(clamp) if clamp else 0.0,
        guiding=options.guiding,
    )


@dataclass(frozen=True)
class BlenderIntrinsics:
    sensor_width: float  # mm, with sensor_fit HORIZONTAL
    lens: float  # mm
    shift_x: float  # fraction of the aspect-scaled image width (the fitted side)
    shift_y: float
    pixel_aspect_x: float
    pixel_aspect_y: float


SENSOR_WIDTH_MM = 36.0


def blender_intrinsics(camera: CameraIR) -> BlenderIntrinsics:
    """Exact Blender camera for a pinhole K (no skew), OpenCV pixel centres at integer coordinates.

    With sensor_fit HORIZONTAL the sensor width spans the W pixels, so fx = W * lens / sensor_width.
    fy != fx is a non-square pixel: Blender scales the view height by (H * pa_y) / (W * pa_x), which gives
    fy = fx * pa_x / pa_y. The optical axis sits at the raster centre W/2 (= OpenCV (W-1)/2) plus
    shift * W * pa_x aspect-scaled pixels, with Blender's y up and OpenCV's v down.
    """
    K = camera.K_array
    W, H = camera.width, camera.height
    fx, fy, cx, cy, skew = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    if abs(skew) > 1e-9 * max(fx, 1.0):
        raise ValueError(f"cycles: camera skew K[0,1]={skew} is not supported by Blender cameras")
    if fx <= 0 or fy <= 0:
        raise ValueError(f"cycles: focal lengths must be positive (fx={fx}, fy={fy})")
    # Blender clamps pixel aspect to >= 1, so the larger of the two is scaled.
    if fy >= fx:
        pax, pay = fy / fx, 1.0
    else:
        pax, pay = 1.0, fx / fy
    # The horizontal view plane is the same whatever the pixel aspect.
    lens = fx * SENSOR_WIDTH_MM / W
    # With sensor_fit HORIZONTAL, shift is a fraction of the fitted (horizontal, aspect-scaled) side,
    # not of the larger side (measured: a portrait frame misplaced the axis by (H - W)/W * offset).
    shift_x = ((W - 1) / 2.0 - cx) / W
    shift_y = (cy - (H - 1) / 2.0) * pay / (W * pax)
    return BlenderIntrinsics(SENSOR_WIDTH_MM, float(lens), float(shift_x), float(shift_y), float(pax), float(pay))


def project(K: np.ndarray, T_w2c: np.ndarray, x_w: np.ndarray) -> np.ndarray:
    """OpenCV projection of world points (N,3) -> pixels (N,2)."""
    x_c = (T_w2c[:3, :3] @ np.asarray(x_w, dtype=np.float64).T).T + T_w2c[:3, 3]
    uv = (K @ x_c.T).T
    return uv[:, :2] / uv[:, 2:3]

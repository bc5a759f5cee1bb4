"""Which Mitsuba variant this machine can run.

A JIT variant can kill the whole process instead of raising (a too-old libLLVM aborts inside
code generation with 'LLVM ERROR: Cannot select ...'), so each candidate is first tried in a child
process that renders a tiny scene, exercising the same code generation a real render does.
"""

from __future__ import annotations

import os
import subprocess
import sys

PREFERENCE = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")

# Renders a 4x4 image with the path integrator: set_variant alone succeeds even where the first
# kernel compilation aborts.
_PROBE = """
import sys, mitsuba as mi
mi.set_variant(sys.argv[1])
scene = mi.load_dict({
    'type': 'scene',
    'integrator': {'type': 'path', 'max_depth': 3},
    'sensor': {'type': 'perspective', 'to_world': mi.ScalarTransform4f().look_at([0, -3, 0], [0, 0, 0], [0, 0, 1]),
               'film': {'type': 'hdrfilm', 'width': 4, 'height': 4}, 'sampler': {'type': 'independent', 'sample_count': 2}},
    'light': {'type': 'constant'},
    'ball': {'type': 'sphere', 'bsdf': {'type': 'principled', 'roughness': 0.3}},
})
img = mi.render(scene)
import numpy as np
v = float(np.asarray(img).mean())
assert np.isfinite(v) and v > 0, v
print('ok')
"""


def probe(variant: str, timeout: float = 120.0) -> tuple[bool, str]:
    """(works, reason) for one variant, tried in a child process."""
    env = dict(os.environ)
    try:
        r = subprocess.run(
            [sys.executable, "-c", _PROBE, variant], capture_output=True, text=True, timeout=timeout, env=env
        )
    except subprocess.TimeoutExpired:
        return False, f"probe timed out after {timeout:.0f} s"
    if r.returncode == 0 and r.stdout.strip().endswith("ok"):
        return True, "ok"
    tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or [f"exit status {r.returncode}"]
    return False, tail[0][:300]


def _gpu_plausible() -> bool:
    # Avoids a multi-second child start on the (common) machines with no NVIDIA driver at all.
    return os.path.exists("/dev/nvidiactl") or os.path.exists("/proc/driver/nvidia/version")


def choose_variant(requested: str = "auto") -> tuple[str, dict[str, str]]:
    """The variant to use and why the better ones were skipped (variant -> reason)."""
    import mitsuba as mi

    compiled = set(mi.variants())
    if requested != "auto":
        return _checked(requested, compiled), {}
    skipped: dict[str, str] = {}
    for v in PREFERENCE:
        if v not in compiled:
            skipped[v] = "not compiled into this Mitsuba build"
            continue
        if v == "scalar_rgb":
            return v, skipped
        if v.startswith("cuda") and not _gpu_plausible():
            skipped[v] = "no NVIDIA driver"
            continue
        ok, why = probe(v)
        if ok:
            return v, skipped
        skipped[v] = why
    raise RuntimeError(f"no usable Mitsuba variant: {skipped}")


def _checked(requested: str, compiled: set[str]) -> str:
    """The variant a spec names, if it runs here; else an error naming the option and the fix
    (a CUDA variant without a GPU would otherwise fail later, inside Dr.Jit, in every render)."""
    field = f"backend.variant is {requested!r}"
    if requested not in compiled:
        raise RuntimeError(f"{field}: not in this Mitsuba build (have: {', '.join(sorted(compiled))})")
    if requested.startswith("cuda") and not _gpu_plausible():
        raise RuntimeError(f"{field}, but this machine has no NVIDIA GPU driver: use 'auto' (picks "
                           "llvm_ad_rgb here) or run on a machine with a GPU")
    if requested != "scalar_rgb":
        ok, why = probe(requested)
        if not ok:
            raise RuntimeError(f"{field}, but it does not run on this machine ({why}); use 'auto'")
    return requested

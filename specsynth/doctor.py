"""``specsynth doctor`` and ``specsynth --version``: what is installed and whether it works.

Each component is one :class:`~specsynth.plugins.Check`: Python, the core's libraries, headless
OpenGL (EGL, which the annotation engine and the photo backend need), the Sweet Home 3D furniture,
the asset sets in the cache (their files against their manifests' sha256), and every installed
backend plugin's own checks (its renderer, its version, the GPU devices it finds). Anything that
can crash or print on the terminal (bpy, Mitsuba's JIT, an EGL context) runs in a child process.
"""

from __future__ import annotations

import importlib
import os
import sys

from .plugins import (
    BACKEND_GROUP,
    PROBE_MARK,
    Check,
    PluginNotFound,
    available_backends,
    backend_plugin,
    dist_version,
    probe_in_child,
)

PYTHON = (3, 11)  # pyproject's requires-python: the bpy wheel exists for 3.11 only
CORE_MODULES = ("numpy", "pydantic", "yaml", "trimesh", "pybullet", "pyrender", "pyarrow", "OpenEXR", "PIL",
                "scipy", "pycocotools", "coacd", "skimage", "ruamel.yaml")

# An EGL context the way the annotation engine makes one, and the OpenGL renderer it got.
_EGL_PROBE = f"""
import os
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
import pyrender
from OpenGL import GL
r = pyrender.OffscreenRenderer(16, 16)
scene = pyrender.Scene()
scene.add(pyrender.PerspectiveCamera(yfov=1.0))
r.render(scene, flags=pyrender.RenderFlags.DEPTH_ONLY)
print({PROBE_MARK!r} + GL.glGetString(GL.GL_RENDERER).decode())
"""
EGL_FIX = "apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri libgles2 (Mesa's EGL; PYOPENGL_PLATFORM=egl)"


def version_lines() -> list[str]:
    """specsynth's version, then each installed backend plugin's distribution and renderer versions."""
    from importlib import metadata

    lines = [f"specsynth {dist_version('specsynth')} (Python {sys.version.split()[0]})"]
    eps = sorted(metadata.entry_points(group=BACKEND_GROUP), key=lambda ep: ep.name)
    for ep in eps:
        dist = f"{ep.dist.name} {ep.dist.version}" if ep.dist is not None else "(not from a distribution)"
        try:
            uses = ", ".join(f"{d} {dist_version(d)}" for d in backend_plugin(ep.name).distributions)
        except PluginNotFound as e:
            uses = f"broken: {e}"
        lines.append(f"  backend {ep.name}: {dist}" + (f" ({uses})" if uses else ""))
    if not eps:
        lines.append("  no backend plugin installed (install a specsynth backend distribution; in this repository: make install)")
    return lines


def python_check() -> Check:
    v = sys.version_info
    ok = (v.major, v.minor) == PYTHON
    return Check("python", ok, f"{sys.version.split()[0]} ({sys.executable})",
                 "" if ok else "use Python 3.11: python3.11 -m venv VENV && VENV/bin/pip install specsynth")


def core_check() -> Check:
    from .processes import import_quietly

    missing = []
    for mod in CORE_MODULES:
        try:
            if mod == "pybullet":  # its first import prints a build-date banner
                import_quietly(mod, "pybullet build time:")
            else:
                importlib.import_module(mod)
        except Exception as e:  # noqa: BLE001 - any failure to import is the finding
            missing.append(f"{mod} ({type(e).__name__})")
    if missing:
        return Check("specsynth core", False, f"{dist_version('specsynth')}; cannot import {', '.join(missing)}",
                     "pip install --force-reinstall specsynth")
    return Check("specsynth core", True, f"{dist_version('specsynth')}; numpy {dist_version('numpy')}, pybullet "
                 f"{dist_version('pybullet')}, trimesh {dist_version('trimesh')}, pyrender {dist_version('pyrender')}")


def egl_check(timeout: float = 120.0) -> Check:
    env = dict(os.environ)
    env.setdefault("PYOPENGL_PLATFORM", "egl")
    name = f"OpenGL (PYOPENGL_PLATFORM={env['PYOPENGL_PLATFORM']})"
    renderer, why = probe_in_child(_EGL_PROBE, timeout, env)
    if renderer is None:
        return Check(name, False, f"no headless context: {why}", EGL_FIX)
    return Check(name, True, f"headless context, renderer {renderer}")


def furniture_check() -> Check:
    from .assets.library.furniture import LibraryError, catalogue, library_dir

    fix = "apt-get install sweethome3d-furniture (Debian; or set SPECSYNTH_SH3D_DIR to its folder)"
    try:
        n = len(catalogue())
    except (LibraryError, OSError) as e:
        return Check("furniture library", False, str(e).splitlines()[0][:200], fix)
    return Check("furniture library", n > 0, f"{n} Sweet Home 3D models in {library_dir()}", "" if n else fix)


def asset_checks() -> list[Check]:
    from .assets.library import install
    from .assets.library.cache import cache_dir

    cache = cache_dir()
    out = []
    for s in install.asset_sets():
        name = f"assets {s.name}"
        if not s.is_installed(cache):
            out.append(Check(name, False, f"not installed in {cache}", "specsynth assets install"))
            continue
        try:
            bad = s.verify(cache)
        except (OSError, ValueError, KeyError) as e:
            out.append(Check(name, False, f"unreadable manifest ({type(e).__name__})", "specsynth assets install --force"))
            continue
        out.append(Check(name, not bad, "installed, every file matches its sha256" if not bad else
                         f"{len(bad)} file(s) differ from the manifest, e.g. {bad[0]}",
                         "" if not bad else "specsynth assets install --force"))
    return out


def backend_checks() -> list[Check]:
    names = available_backends()
    if not names:
        return [Check("backends", False, "no render backend plugin is installed",
                      "install a specsynth backend distribution (in this repository: make install)")]
    out = [Check("backends", True, ", ".join(names))]
    for name in names:
        try:
            plugin = backend_plugin(name)
        except PluginNotFound as e:
            out.append(Check(f"backend {name}", False, str(e), f"pip install --force-reinstall specsynth-{name}"))
            continue
        out += plugin.run_checks()
    return out


def run_checks() -> list[Check]:
    return [python_check(), core_check(), egl_check(), furniture_check(), *asset_checks(), *backend_checks()]


def status(c: Check) -> str:
    if c.ok is None:
        return "info"
    if c.ok:
        return "ok"
    return "PROBLEM" if c.required else "warning"


def report(checks: list[Check], write=print) -> int:
    """A line per component (and its fix) -> 0 when every required component works."""
    width = max(len(c.component) for c in checks)
    for c in checks:
        write(f"{status(c):8s}{c.component:{width}s}  {c.detail}")
        if c.ok is False and c.fix:
            write(f"{'':8s}{'':{width}s}  fix: {c.fix}")
    problems = [c for c in checks if c.ok is False and c.required]
    warnings = [c for c in checks if c.ok is False and not c.required]
    if problems:
        write(f"{len(problems)} problem(s): fix them and run `specsynth doctor` again")
        return 1
    write("everything specsynth needs works" + (f" ({len(warnings)} warning(s))" if warnings else ""))
    return 0


def cache_note() -> str:
    from .assets.library.cache import cache_dir

    return f"cache: {cache_dir()} (SPECSYNTH_CACHE to move it)"


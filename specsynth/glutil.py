"""pyrender helpers shared by the annotation engine and OpenGL backends.

pyrender picks its OpenGL platform when it is imported; EGL is the one that works headless here
(OSMesa fails with the pinned PyOpenGL). A caller that has already chosen a platform keeps it.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pyrender  # noqa: E402

from .conventions import opengl_projection  # noqa: E402


class KCamera(pyrender.Camera):
    """Pinhole camera given by an OpenCV intrinsic matrix (skew and off-centre principal point kept)."""

    def __init__(self, K: np.ndarray, znear: float, zfar: float):
        super().__init__(znear=znear, zfar=zfar)
        self.K = np.asarray(K, dtype=np.float64)

    def get_projection_matrix(self, width=None, height=None):
        return opengl_projection(self.K, width, height, self.znear, self.zfar)


def release_renderer(renderer: pyrender.OffscreenRenderer) -> None:
    """Free a renderer's GL objects and context *without* ``eglTerminate``.

    pyrender's ``OffscreenRenderer.delete`` (also run by its ``__del__``) terminates the EGL
    display, and every EGL context in the process shares that display: deleting one renderer
    breaks every other one alive (the annotation engine's, another backend instance's) with
    ``EGL_BAD_DISPLAY`` on their next ``eglMakeCurrent``.
    """
    platform = getattr(renderer, "_platform", None)
    if platform is None:
        return
    try:
        platform.make_current()
        renderer._renderer.delete()
    except Exception:  # noqa: BLE001 - the context may already be dead; nothing left to free then
        pass
    finally:
        display = getattr(platform, "_egl_display", None)
        if display is not None:
            from OpenGL.EGL import EGL_NO_CONTEXT, EGL_NO_SURFACE, eglDestroyContext, eglMakeCurrent

            try:
                eglMakeCurrent(display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
                if platform._egl_context is not None:
                    eglDestroyContext(display, platform._egl_context)
            except Exception:  # noqa: BLE001 - display terminated by someone else: context gone
                pass
            platform._egl_context = None
            platform._egl_display = None
        else:
            platform.delete_context()
        # Disarm OffscreenRenderer.__del__, which would call delete() and terminate the display.
        renderer._renderer = None
        renderer._platform = None


def discard_renderer(renderer: pyrender.OffscreenRenderer) -> None:
    """Forget a renderer whose context is already gone, making no GL call."""
    renderer._renderer = None
    renderer._platform = None

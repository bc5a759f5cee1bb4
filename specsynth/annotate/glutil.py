"""pyrender helpers shared by the annotation engine and OpenGL backends.

pyrender picks its OpenGL platform when it is imported; EGL is the one that works headless here
(OSMesa fails with the pinned PyOpenGL). A caller that has already chosen a platform keeps it.
"""

from __future__ import annotations

import os

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pyrender  # noqa: E402

from ..model.conventions import opengl_projection  # noqa: E402


class KCamera(pyrender.Camera):
    """Pinhole camera given by an OpenCV intrinsic matrix (skew and off-centre principal point kept)."""

    def __init__(self, K: np.ndarray, znear: float, zfar: float):
        super().__init__(znear=znear, zfar=zfar)
        self.K = np.asarray(K, dtype=np.float64)

    def get_projection_matrix(self, width=None, height=None):
        return opengl_projection(self.K, width, height, self.znear, self.zfar)


def texture_from_file(path: str) -> pyrender.Texture:
    """An sRGB image file as a mip-mapped pyrender texture (the shader linearises it, as glTF)."""
    from PIL import Image

    with Image.open(path) as im:
        rgb = np.asarray(im.convert("RGB"), dtype=np.uint8)
    # Four bytes a texel: OpenGL reads texture rows 4-byte aligned and pyrender never says
    # otherwise, so an RGB texture of odd width (robosuite's 255 px floor tile) was read past its
    # rows' ends, into memory that differs from run to run (a speckled seam; albedo not repeatable).
    img = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 255, np.uint8)], axis=-1)
    sampler = pyrender.Sampler(magFilter=pyrender.constants.GLTF.LINEAR,
                               minFilter=pyrender.constants.GLTF.LINEAR_MIPMAP_LINEAR)
    return pyrender.Texture(source=img, source_channels="RGBA", sampler=sampler)


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


SHADER_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "shaders")


def draw_in_name_order(renderer: pyrender.OffscreenRenderer) -> None:
    """Draw meshes far to near as pyrender does, and meshes at the same distance by node name.

    pyrender breaks ties in the order of a set of nodes, which changes from process to process;
    coplanar surfaces (a furniture model's parts share one pose) then z-fight differently in every
    run, and a colour image (albedo, the photo and flat backends) is not the same twice."""
    inner = renderer._renderer

    def ordered(scene):
        cam = scene.get_pose(scene.main_camera_node)[:3, 3]

        def key(n):
            return (-float(np.linalg.norm(scene.get_pose(n)[:3, 3] - cam)), n.name or "")
        nodes = sorted(scene.mesh_nodes, key=key)
        return [n for n in nodes if not n.mesh.is_transparent] + [n for n in nodes if n.mesh.is_transparent]

    inner._sorted_mesh_nodes = ordered


def use_depth_pass(renderer: pyrender.OffscreenRenderer) -> None:
    """Make a renderer's SEG pass what the annotation engine needs (it renders nothing else).

    pyrender's SEG pass culls back faces whatever the flags say, so a camera behind a wall saw
    through it; here both faces of every triangle are drawn. And a primitive whose material has a
    ``baseColorTexture`` uses it as a coverage map: texels under one half are holes.
    """
    inner = renderer._renderer
    inner._program_cache = pyrender.shader_program.ShaderProgramCache(shader_dir=SHADER_DIR)
    inner._bind_and_draw_primitive = _draw_both_faces.__get__(inner)


def _draw_both_faces(self, primitive, pose, program, flags):
    from OpenGL import GL

    program.set_uniform("M", pose)
    primitive._bind()
    material = primitive.material
    if primitive.texcoord_0 is not None and material is not None and material.baseColorTexture is not None:
        self._bind_texture(material.baseColorTexture, "coverage", program)
        rows = getattr(material, "uv_rows", ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0)))
        program.set_uniform("uv_row0", np.asarray(rows[0], np.float32))
        program.set_uniform("uv_row1", np.asarray(rows[1], np.float32))
    GL.glDisable(GL.GL_CULL_FACE)
    GL.glEnable(GL.GL_BLEND)
    GL.glBlendFunc(GL.GL_ONE, GL.GL_ZERO)
    GL.glPolygonMode(GL.GL_FRONT_AND_BACK, GL.GL_FILL)
    n = 1 if primitive.poses is None else len(primitive.poses)
    if primitive.indices is not None:
        GL.glDrawElementsInstanced(primitive.mode, primitive.indices.size, GL.GL_UNSIGNED_INT, None, n)
    else:
        GL.glDrawArraysInstanced(primitive.mode, 0, len(primitive.positions), n)
    primitive._unbind()

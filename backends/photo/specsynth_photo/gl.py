"""pyrender pieces of the photo backend: a camera that reproduces an OpenCV K exactly, a renderer
with a selectable MSAA sample count, safe release of EGL contexts, and meshes built from the
normalised PLY form with the IR's material."""

from __future__ import annotations

import os

# pyrender picks its OpenGL platform when it is imported; EGL is the one that works headless here
# (OSMesa fails). A caller that has already chosen a platform keeps it.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import numpy as np  # noqa: E402
import pyrender  # noqa: E402
from OpenGL.GL import (  # noqa: E402
    GL_DEPTH_COMPONENT24,
    GL_RENDERBUFFER,
    GL_RGBA,
    glBindRenderbuffer,
    glRenderbufferStorageMultisample,
)
from pyrender.renderer import Renderer  # noqa: E402

from specsynth.annotate.glutil import (  # noqa: E402,F401  (re-exported)
    KCamera,
    discard_renderer,
    draw_in_name_order,
    release_renderer,
    texture_from_file,
)
from specsynth.assets.meshio import MeshData, read_mesh  # noqa: E402
from specsynth.model.colour import srgb_to_linear  # noqa: E402
from specsynth.model.ir import MaterialIR  # noqa: E402


class SampledRenderer(Renderer):
    """pyrender's renderer with a chosen MSAA sample count for the main framebuffer.

    pyrender always renders into a 4x multisampled buffer; on Mesa's llvmpipe that makes a
    640x480 frame of ~10 objects about 4x slower (measured 0.06-0.1 s vs 0.28-0.44 s, loaded
    2-core machine). With ``samples = 0`` the buffer is single-sampled: aliased edges, rasterised
    like pyrender's (non-multisampled) segmentation pass that masks are made with.
    """

    def __init__(self, width: int, height: int, samples: int = 4):
        super().__init__(width, height)
        self.samples = samples
        self._applied_samples: int | None = None

    def _configure_main_framebuffer(self):
        created = self._main_fb is None or self._main_fb_dims != (self.viewport_width, self.viewport_height)
        super()._configure_main_framebuffer()
        if created or self._applied_samples != self.samples:
            # Re-specifying the storage keeps the attachments; only the sample count changes.
            w, h = self.viewport_width, self.viewport_height
            glBindRenderbuffer(GL_RENDERBUFFER, self._main_cb_ms)
            glRenderbufferStorageMultisample(GL_RENDERBUFFER, self.samples, GL_RGBA, w, h)
            glBindRenderbuffer(GL_RENDERBUFFER, self._main_db_ms)
            glRenderbufferStorageMultisample(GL_RENDERBUFFER, self.samples, GL_DEPTH_COMPONENT24, w, h)
            self._applied_samples = self.samples


class Scene(pyrender.Scene):
    """A pyrender scene that hands its lights to the shader in the order of their names.

    pyrender gathers lights from sets of nodes, iterated in the order of the nodes' addresses,
    which follow the process's heap. The shader sums the lights in that order, and float addition
    is not associative: with three lights of one kind a pixel now and then rounds to the other
    8-bit level (one pixel in 40 VGA views), and with more lights of one kind than the shader
    takes (4), the ones it keeps depended on the heap. Then a JPEG depended on which worker drew it.
    """

    @property
    def light_nodes(self):
        return sorted(super().light_nodes, key=lambda n: n.name or "")


def new_renderer(width: int, height: int, samples: int) -> pyrender.OffscreenRenderer:
    r = pyrender.OffscreenRenderer(width, height)
    # The Renderer made by OffscreenRenderer has allocated no GL object yet: swap in ours.
    r._renderer = SampledRenderer(width, height, samples)
    draw_in_name_order(r)
    return r


def vertex_normals(mesh: MeshData) -> np.ndarray:
    """Area-weighted vertex normals, for meshes stored without normals."""
    v = mesh.vertices.astype(np.float64)
    f = mesh.faces
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 * area
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return (n / np.where(length > 0, length, 1.0)).astype(np.float32)


def build_mesh(path: str, material: MaterialIR, textures: dict[str, pyrender.Texture]) -> pyrender.Mesh:
    """A pyrender mesh of a normalised PLY with a metallic-roughness version of ``material``."""
    mesh = read_mesh(path).validate(path)
    normals = mesh.normals if mesh.normals is not None else vertex_normals(mesh)
    texcoord = None
    tex = None
    if material.texture is not None and mesh.uv is not None:
        tex = textures.get(material.texture)
        if tex is None:
            tex = textures[material.texture] = texture_from_file(material.texture)
        texcoord = mesh.uv
    color_0 = None
    if material.use_vertex_colors and mesh.colors is not None:
        # pyrender multiplies the *shaded* colour by COLOR_0, in linear space: pass linear colours
        # and opaque alpha (an alpha < 1 would send the mesh down pyrender's transparent path).
        color_0 = np.ones((len(mesh.vertices), 4), dtype=np.float32)
        color_0[:, :3] = srgb_to_linear(mesh.colors[:, :3].astype(np.float32) / 255.0)
    # pyrender adds emissive_factor squared (factor * factor); its square root gives the IR value.
    emissive = np.sqrt(np.clip(np.asarray(material.emission, dtype=np.float64), 0.0, None))
    mat = pyrender.MetallicRoughnessMaterial(
        baseColorFactor=(*material.base_color, 1.0),
        metallicFactor=float(material.metallic),
        roughnessFactor=float(material.roughness),
        emissiveFactor=emissive,
        baseColorTexture=tex,
        # Both sides drawn, like the path tracers do, so open meshes are not see-through.
        doubleSided=True,
        alphaMode="OPAQUE",
    )
    prim = pyrender.Primitive(
        positions=mesh.vertices,
        normals=normals,
        texcoord_0=texcoord,
        color_0=color_0,
        indices=mesh.faces,
        material=mat,
        mode=pyrender.constants.GLTF.TRIANGLES,
    )
    return pyrender.Mesh(primitives=[prim])

"""The ``flat`` renderer: every mesh in its base colour (times its base-colour texture), unlit."""

from __future__ import annotations

import os
from importlib import metadata
from typing import Any, ClassVar

os.environ.setdefault("PYOPENGL_PLATFORM", "egl")  # headless: before OpenGL is imported

import numpy as np  # noqa: E402
import pyrender  # noqa: E402

from specsynth.annotate.glutil import (  # noqa: E402
    KCamera,
    draw_in_name_order,
    release_renderer,
    texture_from_file,
)
from specsynth.assets.meshio import read_mesh  # noqa: E402
from specsynth.model.conventions import cam_to_world, opencv_to_opengl_c2w  # noqa: E402
from specsynth.model.ir import CameraIR, MaterialIR, RenderResult, RenderScene  # noqa: E402
from specsynth.spec.models import QualityPreset  # noqa: E402

from . import FlatOptions  # noqa: E402


class FlatBackend:
    name: ClassVar[str] = "flat"

    def __init__(self, options: Any = None, *, threads: int = 0) -> None:
        self.options = options if isinstance(options, FlatOptions) else FlatOptions.model_validate(
            {**dict(options or {}), "name": "flat"})
        self._renderer: pyrender.OffscreenRenderer | None = None
        self._scene: pyrender.Scene | None = None

    def version(self) -> str:
        return f"flat-1 pyrender-{metadata.version('pyrender')}"

    def load(self, scene: RenderScene) -> None:
        bg = [c ** 2.2 for c in self.options.background]  # pyrender encodes its output with a 1/2.2 power
        self._scene = pyrender.Scene(bg_color=(*bg, 1.0), ambient_light=(0.0, 0.0, 0.0))
        textures: dict[str, pyrender.Texture] = {}
        for inst in scene.meshes:
            self._scene.add(_mesh(inst.mesh_path, inst.material, textures), pose=inst.matrix, name=inst.name)

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None) -> RenderResult:
        if self._scene is None:
            raise RuntimeError("flat backend: render() called before load()")
        w, h = int(camera.width), int(camera.height)
        if self._renderer is None or (self._renderer.viewport_width, self._renderer.viewport_height) != (w, h):
            self.close_renderer()
            self._renderer = pyrender.OffscreenRenderer(w, h)
            draw_in_name_order(self._renderer)
        pose = opencv_to_opengl_c2w(cam_to_world(camera.R_w2c, camera.t_w2c))
        node = self._scene.add(KCamera(camera.K_array, camera.near, camera.far), pose=pose)
        try:
            rgb, _ = self._renderer.render(self._scene, flags=pyrender.RenderFlags.FLAT)
        finally:
            self._scene.remove_node(node)
        return RenderResult(rgb=np.ascontiguousarray(rgb[..., :3]), linear=None, stats={})

    def close_renderer(self) -> None:
        if self._renderer is not None:
            release_renderer(self._renderer)
            self._renderer = None

    def close(self) -> None:
        self.close_renderer()
        self._scene = None


def _mesh(path: str, material: MaterialIR, textures: dict[str, pyrender.Texture]) -> pyrender.Mesh:
    mesh = read_mesh(path).validate(path)
    tex = None
    if material.texture is not None and mesh.uv is not None:
        if material.texture not in textures:  # mip-mapped (no moire far away), rows 4-byte aligned
            textures[material.texture] = texture_from_file(material.texture)
        tex = textures[material.texture]
    mat = pyrender.MetallicRoughnessMaterial(baseColorFactor=(*material.base_color, 1.0), baseColorTexture=tex,
                                             doubleSided=True, alphaMode="OPAQUE")
    prim = pyrender.Primitive(positions=mesh.vertices, texcoord_0=mesh.uv if tex is not None else None,
                              indices=mesh.faces, material=mat, mode=pyrender.constants.GLTF.TRIANGLES)
    return pyrender.Mesh(primitives=[prim])

"""Albedo maps: every surface's diffuse colour (base colour x base-colour texture x vertex
colours), unlit, rasterised with pyrender from the same scene and camera as the labels, so every
backend gets the same map. Written as 8-bit sRGB PNG, like the colour image.

Its own renderer and scene (the annotation engine's renderer draws depth with its own shaders);
meshes and textures are cached by content across arrangements.
"""

from __future__ import annotations

import numpy as np

from ..assets.meshio import read_mesh
from ..model.colour import linear_to_srgb, srgb_to_linear
from ..model.conventions import cam_to_world, opencv_to_opengl_c2w
from ..model.ir import CameraIR, MaterialIR, MeshInstance, RenderScene
from . import glutil

# pyrender's flat shader multiplies its inputs as given and writes the product: the texture as its
# file encodes it (sRGB, read here as a 1/2.2 power), so the base colour and the vertex colours are
# given in the same 1/2.2 power (a product of powers is the power of the product), and the output,
# decoded with it, is encoded with the sRGB curve.
GAMMA = 2.2
_GAMMA_TO_SRGB = np.round(linear_to_srgb((np.arange(256) / 255.0) ** GAMMA) * 255.0).astype(np.uint8)


class AlbedoRenderer:
    def __init__(self, width: int, height: int):
        self.width, self.height = int(width), int(height)
        self._pr = glutil.pyrender
        self._renderer = self._pr.OffscreenRenderer(self.width, self.height)
        glutil.draw_in_name_order(self._renderer)
        self._scene = None
        self._meshes: dict[tuple, object] = {}
        self._textures: dict[str, object] = {}

    def load(self, scene: RenderScene) -> None:
        self._scene = self._pr.Scene(bg_color=(0.0, 0.0, 0.0, 1.0), ambient_light=(0.0, 0.0, 0.0))
        for inst in scene.meshes:
            self._scene.add(self._mesh(inst), pose=inst.matrix, name=inst.name)
        # Keep only what this arrangement draws: with a new room per arrangement the caches would
        # otherwise grow with every one (pyrender frees the GL side of meshes left out of a scene).
        live = {_mesh_key(inst) for inst in scene.meshes}
        self._meshes = {k: v for k, v in self._meshes.items() if k in live}
        self._textures = {k: v for k, v in self._textures.items() if any(k == m.material.texture for m in scene.meshes)}

    def render(self, camera: CameraIR) -> np.ndarray:
        """HxWx3 uint8 sRGB diffuse colour seen by ``camera`` (black where nothing is)."""
        pose = opencv_to_opengl_c2w(cam_to_world(camera.R_w2c, camera.t_w2c))
        node = self._scene.add(glutil.KCamera(camera.K_array, camera.near, camera.far), pose=pose)
        try:
            F = self._pr.RenderFlags
            rgb, _ = self._renderer.render(self._scene, flags=F.FLAT | F.SKIP_CULL_FACES)
        finally:
            self._scene.remove_node(node)
        return _GAMMA_TO_SRGB[np.asarray(rgb)[..., :3]]

    def close(self) -> None:
        glutil.release_renderer(self._renderer)
        self._meshes.clear()
        self._textures.clear()

    def _mesh(self, inst: MeshInstance):
        key = _mesh_key(inst)
        if key not in self._meshes:
            self._meshes[key] = self._build(inst.mesh_path, inst.material)
        return self._meshes[key]

    def _build(self, path: str, m: MaterialIR):
        pr = self._pr
        data = read_mesh(path).validate(path)
        tex, uv = None, None
        if m.texture is not None and data.uv is not None:
            tex = self._texture(m.texture)
            a, b, c, d, e, f = m.uv_transform
            u, v = data.uv[:, 0].astype(np.float64), data.uv[:, 1].astype(np.float64)
            uv = np.stack([a * u + b * v + c, d * u + e * v + f], axis=1).astype(np.float32)
        colors = None
        if m.use_vertex_colors and data.colors is not None:
            colors = np.ones((len(data.vertices), 4), np.float32)
            colors[:, :3] = srgb_to_linear(data.colors[:, :3].astype(np.float32) / 255.0) ** (1 / GAMMA)
        base = tuple(float(c) ** (1 / GAMMA) for c in m.base_color)
        mat = pr.MetallicRoughnessMaterial(baseColorFactor=(*base, 1.0), baseColorTexture=tex,
                                           doubleSided=True, alphaMode="OPAQUE")
        prim = pr.Primitive(positions=data.vertices, texcoord_0=uv, color_0=colors, indices=data.faces,
                            material=mat, mode=pr.constants.GLTF.TRIANGLES)
        return pr.Mesh([prim])

    def _texture(self, path: str):
        if path not in self._textures:
            self._textures[path] = glutil.texture_from_file(path)
        return self._textures[path]


def _mesh_key(inst: MeshInstance) -> tuple:
    m = inst.material
    return (inst.mesh_key, m.base_color, m.texture, m.use_vertex_colors, m.uv_transform)

"""The annotation engine: masks, depth and BOP ``scene_gt_info`` numbers, shared by every backend.

Masks and visibility come from depth-only rasterisation with pyrender over EGL, never from the
RGB backend, so annotations are identical whatever renders the images.

Semantics are those of the BOP toolkit's ``scripts/calc_gt_info.py`` (BOP19 visibility):

- each object is rendered *alone* on a canvas 3x the image size, centred on the image, so the
  truncated part of its silhouette counts: ``px_count_all`` and ``bbox_obj`` come from it;
- object and scene depth are converted to distance from the camera centre (BOP's
  ``depth_im_to_dist_im``) and a pixel of the object's in-image silhouette is visible where
  ``d_obj - d_scene <= delta`` or the scene has no depth there;
- ``px_count_valid`` counts in-image silhouette pixels with scene depth;
- ``bbox_*`` are ``[x, y, xmax - xmin, ymax - ymin]`` (BOP's ``calc_2d_bbox``), and both are
  ``[-1, -1, -1, -1]`` when no pixel is visible (BOP only fills ``bbox_obj`` when
  ``px_count_visib > 0``).

Speed: an object alone is rendered only inside the window of the 3x canvas that its projected
convex hull can cover. Pixel-centre coverage does not depend on which window is rasterised, so
this equals the full 3x render but costs a few milliseconds instead of ~70 ms.
Pixel centres: pyrender's multisampling would sample off-centre, so renders use its SEG path
(multisampling off; ``seg_node_map`` also selects which nodes are drawn) with
``specsynth.model.conventions.opengl_projection``, which puts pixel centres where ``K`` does.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass
from typing import Literal

import numpy as np

from specsynth.annotate import glutil
from specsynth.assets.meshio import read_mesh
from specsynth.model.conventions import cam_to_world, model_to_camera, opencv_to_opengl_c2w
from specsynth.model.ir import CameraIR, MeshInstance, RenderScene
from specsynth.model.records import InstanceGT

# PyOpenGL binds its platform at first import; EGL is the only headless one that works here
# (OSMesa does not). setdefault keeps a caller's explicit choice.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

EMPTY_BBOX = [-1, -1, -1, -1]


def _look(forward, down) -> np.ndarray:
    """World-to-camera rotation of an OpenCV camera (x right, y down, z forward)."""
    z, y = np.asarray(forward, float), np.asarray(down, float)
    return np.stack([np.cross(y, z), y, z])


# The six 90-degree views of a cube map.
_CUBE_FACES = tuple(_look(f, d) for f, d in (
    ((1, 0, 0), (0, 0, -1)), ((-1, 0, 0), (0, 0, -1)), ((0, 1, 0), (0, 0, -1)),
    ((0, -1, 0), (0, 0, -1)), ((0, 0, 1), (0, 1, 0)), ((0, 0, -1), (0, 1, 0)),
))


@dataclass
class Annotation:
    instances: list[InstanceGT]  # gt order (RenderScene.objects()); poses in metres
    masks: list[np.ndarray]  # bool HxW: full (amodal) silhouette within the image
    masks_visib: list[np.ndarray]  # bool HxW
    depth: np.ndarray  # float32 HxW z-depth (m) of the occluders, 0 where empty


@dataclass
class _ObjectView:
    """One object rendered alone, cut to the 3x canvas; coordinates are image pixels."""

    x0: int
    y0: int
    depth: np.ndarray  # float32 window of the 3x canvas, 0 where empty

    def in_image(self, width: int, height: int) -> tuple[int, int, int, int] | None:
        h, w = self.depth.shape
        ix0, iy0 = max(self.x0, 0), max(self.y0, 0)
        ix1, iy1 = min(self.x0 + w, width), min(self.y0 + h, height)
        if ix0 >= ix1 or iy0 >= iy1:
            return None
        return ix0, iy0, ix1, iy1


@dataclass
class _Info:
    px_count_all: int
    px_count_valid: int
    px_count_visib: int
    visib_fract: float
    bbox_obj: list[int]
    bbox_visib: list[int]
    mask: np.ndarray | None = None  # HxW, filled when asked for
    mask_visib: np.ndarray | None = None


def bbox_from_mask(mask: np.ndarray, x_offset: int = 0, y_offset: int = 0) -> list[int]:
    """BOP's ``calc_2d_bbox`` of a mask's pixels: ``[x, y, xmax - xmin, ymax - ymin]``."""
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return list(EMPTY_BBOX)
    cols = np.flatnonzero(mask.any(axis=0))
    return [int(cols[0] + x_offset), int(rows[0] + y_offset), int(cols[-1] - cols[0]), int(rows[-1] - rows[0])]


def depth_to_dist_factor(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Per-pixel factor turning z-depth into distance from the camera centre (BOP's convention:
    pixel (x, y) is the ray through integer coordinates (x, y); skew ignored)."""
    K = np.asarray(K, dtype=np.float64)
    xs = (np.arange(width, dtype=np.float64) - K[0, 2]) / K[0, 0]
    ys = (np.arange(height, dtype=np.float64) - K[1, 2]) / K[1, 1]
    return np.sqrt(xs[None, :] ** 2 + ys[:, None] ** 2 + 1.0)


def _gt_info(
    obj: _ObjectView, scene_depth: np.ndarray, scene_x0: int, scene_y0: int, factor: np.ndarray,
    width: int, height: int, delta: float, with_masks: bool,
) -> _Info:
    """BOP ``calc_gt_info`` numbers of one object from its alone-render and the scene depth.

    ``scene_depth`` is a window of the scene's z-depth with origin (scene_x0, scene_y0) covering
    at least the object's in-image window; ``factor`` is :func:`depth_to_dist_factor` (HxW).
    """
    mask_win = obj.depth > 0
    px_all = int(np.count_nonzero(mask_win))
    roi = obj.in_image(width, height) if px_all else None
    if roi is None:
        empty = np.zeros((height, width), bool) if with_masks else None
        return _Info(px_all, 0, 0, 0.0, list(EMPTY_BBOX), list(EMPTY_BBOX), empty, empty)
    ix0, iy0, ix1, iy1 = roi
    d_obj = obj.depth[iy0 - obj.y0 : iy1 - obj.y0, ix0 - obj.x0 : ix1 - obj.x0]
    d_scene = scene_depth[iy0 - scene_y0 : iy1 - scene_y0, ix0 - scene_x0 : ix1 - scene_x0]
    f = factor[iy0:iy1, ix0:ix1]
    # BOP compares float64 distances cast to float32
    dist_obj = (d_obj * f).astype(np.float32)
    dist_scene = (d_scene * f).astype(np.float32)
    m = dist_obj > 0
    visib = m & ((dist_obj - dist_scene <= np.float32(delta)) | (dist_scene == 0))
    px_valid = int(np.count_nonzero(m & (dist_scene > 0)))
    px_visib = int(np.count_nonzero(visib))
    if px_visib > 0:
        bbox_obj = bbox_from_mask(mask_win, obj.x0, obj.y0)
        bbox_visib = bbox_from_mask(visib, ix0, iy0)
    else:
        bbox_obj, bbox_visib = list(EMPTY_BBOX), list(EMPTY_BBOX)
    info = _Info(px_all, px_valid, px_visib, px_visib / px_all, bbox_obj, bbox_visib)
    if with_masks:
        info.mask = np.zeros((height, width), bool)
        info.mask[iy0:iy1, ix0:ix1] = m
        info.mask_visib = np.zeros((height, width), bool)
        info.mask_visib[iy0:iy1, ix0:ix1] = visib
    return info


def _hull_points(vertices: np.ndarray) -> np.ndarray:
    """Vertices of the convex hull (float64): the projected silhouette lies inside their hull."""
    v = np.asarray(vertices, dtype=np.float64)
    if len(v) <= 64:
        return v
    try:
        from scipy.spatial import ConvexHull

        return v[ConvexHull(v).vertices]
    except Exception:  # flat or degenerate meshes: every vertex is still a valid bound
        return v


class _CachedMesh:
    def __init__(self, mesh, keeper, vertices: np.ndarray):
        self.mesh = mesh  # pyrender.Mesh, shared by every node of this mesh_key
        self.keeper = keeper  # never-drawn node that keeps the GPU buffers alive across loads
        self.vertices = vertices
        self._hull: np.ndarray | None = None

    @property
    def hull(self) -> np.ndarray:
        if self._hull is None:
            self._hull = _hull_points(self.vertices)
        return self._hull


def _cache_key(inst: MeshInstance) -> str:
    """Meshes are cached by content; one cut by a coverage map also by the map and its mapping."""
    m = inst.material
    if not m.transparent:
        return inst.mesh_key
    return f"{inst.mesh_key}|{m.opacity_texture}|{m.opacity >= 0.5}|{m.uv_transform}|{m.wrap}"


class Annotator:
    """Annotation engine for one image size; load a :class:`RenderScene` once per arrangement."""

    def __init__(self, width: int, height: int, max_cached_meshes: int = 256):
        pyrender = glutil.pyrender

        self.width, self.height = int(width), int(height)
        self._pr = pyrender
        F = pyrender.RenderFlags
        # SEG turns multisampling off (pixel-centre coverage); culling off for bad winding
        self._flags = F.DEPTH_ONLY | F.SEG | F.SKIP_CULL_FACES
        self._renderer = pyrender.OffscreenRenderer(self.width, self.height)
        glutil.use_depth_pass(self._renderer)  # both faces drawn; coverage maps cut holes
        self._pscene = pyrender.Scene(bg_color=(0, 0, 0, 0), ambient_light=(0, 0, 0))
        self._camera = glutil.KCamera(np.eye(3), 0.01, 100.0)
        self._camera_node = self._pscene.add(self._camera)
        self._cache: OrderedDict[str, _CachedMesh] = OrderedDict()
        self._max_cached = max(1, int(max_cached_meshes))
        self._scene: RenderScene | None = None
        self._nodes: list = []  # every mesh instance of the loaded scene
        self._object_nodes: list = []  # gt order
        self._objects: tuple[MeshInstance, ...] = ()
        self._by_inst: dict[int, int] = {}
        self._factor_key = None
        self._factor: np.ndarray | None = None

    # ------------------------------------------------------------------ scene

    def load(self, scene: RenderScene) -> None:
        for node in self._nodes:
            self._pscene.remove_node(node)
        self._nodes, self._object_nodes = [], []
        node_of: dict[int, object] = {}  # by identity: objects() returns the same instances
        for inst in scene.meshes:
            cached = self._mesh(inst)
            node = self._pscene.add(cached.mesh, name=inst.name, pose=inst.matrix)
            self._nodes.append(node)
            node_of[id(inst)] = node
        self._objects = scene.objects()
        self._object_nodes = [node_of[id(o)] for o in self._objects]
        self._by_inst = {o.inst: i for i, o in enumerate(self._objects)}
        self._scene = scene
        self._evict()

    def _mesh(self, inst: MeshInstance) -> _CachedMesh:
        key = _cache_key(inst)
        cached = self._cache.get(key)
        if cached is None:
            data = read_mesh(inst.mesh_path).validate(inst.mesh_path)
            m = inst.material
            coverage = m.opacity_texture if (m.transparent and data.uv is not None) else None
            prim = self._pr.Primitive(
                positions=data.vertices.astype(np.float32),
                indices=data.faces.astype(np.uint32),
                texcoord_0=None if coverage is None else data.uv.astype(np.float32),
                material=None if coverage is None else self._coverage_material(m),
                mode=self._pr.constants.GLTF.TRIANGLES,
            )
            mesh = self._pr.Mesh([prim])
            mesh.is_visible = not (m.transparent and m.opacity_texture is None and m.opacity < 0.5)
            keeper = self._pscene.add(mesh, name=f"keep:{key}")
            cached = self._cache[key] = _CachedMesh(mesh, keeper, data.vertices)
        self._cache.move_to_end(key)
        return cached

    def _coverage_material(self, m):
        """A pyrender material carrying the coverage map (drawn by glutil.use_depth_pass)."""
        from PIL import Image

        pr = self._pr
        wrap = {"repeat": pr.constants.GLTF.REPEAT, "clamp": pr.constants.GLTF.CLAMP_TO_EDGE,
                "mirror": pr.constants.GLTF.MIRRORED_REPEAT}[m.wrap]
        with Image.open(m.opacity_texture) as im:
            texels = np.asarray(im.convert("L"))
        sampler = pr.Sampler(magFilter=pr.constants.GLTF.NEAREST, minFilter=pr.constants.GLTF.NEAREST,
                             wrapS=wrap, wrapT=wrap)
        material = pr.MetallicRoughnessMaterial(
            baseColorTexture=pr.Texture(source=texels, source_channels="R", sampler=sampler))
        material.uv_rows = (tuple(m.uv_transform[:3]), tuple(m.uv_transform[3:]))
        return material

    def _evict(self) -> None:
        in_use = {_cache_key(m) for m in self._scene.meshes} if self._scene else set()
        for key in list(self._cache):
            if len(self._cache) <= self._max_cached:
                break
            if key not in in_use:
                # the renderer frees GPU buffers of meshes no longer in the scene
                self._pscene.remove_node(self._cache.pop(key).keeper)

    def _require_scene(self) -> RenderScene:
        if self._scene is None:
            raise RuntimeError("Annotator.load(scene) must be called first")
        return self._scene

    # ------------------------------------------------------------------ rendering

    def _set_camera(self, camera: CameraIR) -> None:
        if (camera.width, camera.height) != (self.width, self.height):
            raise ValueError(
                f"camera is {camera.width}x{camera.height}, annotator is {self.width}x{self.height}"
            )
        self._camera.znear, self._camera.zfar = float(camera.near), float(camera.far)
        T = opencv_to_opengl_c2w(cam_to_world(np.asarray(camera.R_w2c), np.asarray(camera.t_w2c)))
        self._pscene.set_pose(self._camera_node, T)
        key = camera.K
        if key != self._factor_key:
            self._factor = depth_to_dist_factor(camera.K_array, self.width, self.height)
            self._factor_key = key

    def _render(self, camera: CameraIR, nodes, x0: int, y0: int, x1: int, y1: int) -> np.ndarray:
        """z-depth (float32, 0 = empty) of ``nodes`` in image-pixel window [x0, x1) x [y0, y1)."""
        if not nodes:
            return np.zeros((y1 - y0, x1 - x0), np.float32)
        K = camera.K_array.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return self._depth(K, x1 - x0, y1 - y0, nodes)

    def _depth(self, K: np.ndarray, w: int, h: int, nodes) -> np.ndarray:
        """z-depth (float32, 0 = empty) of ``nodes`` in a ``w`` x ``h`` image of intrinsics ``K``
        from the pose ``_set_camera`` gave."""
        self._camera.K = K
        self._renderer.viewport_width, self._renderer.viewport_height = w, h
        depth = self._renderer.render(self._pscene, self._flags, seg_node_map={n: (255, 255, 255) for n in nodes})
        return np.asarray(depth, dtype=np.float32)

    def _window(self, camera: CameraIR, k: int) -> tuple[int, int, int, int] | None:
        """Window of the 3x canvas (image pixels) that object k can cover; None if it covers none."""
        W, H = self.width, self.height
        canvas = (-W, -H, 2 * W, 2 * H)
        obj = self._objects[k]
        hull = self._cache[obj.mesh_key].hull
        T = camera.T_w2c @ obj.matrix
        pc = hull @ T[:3, :3].T + T[:3, 3]
        z = pc[:, 2]
        if (z < camera.near).all() or (z > camera.far).all():
            return None  # entirely clipped by the near or far plane
        if (z <= camera.near).any():
            return canvas  # projections of points behind the near plane bound nothing
        K = camera.K_array
        u = K[0, 0] * pc[:, 0] / z + K[0, 1] * pc[:, 1] / z + K[0, 2]
        v = K[1, 1] * pc[:, 1] / z + K[1, 2]
        # a pixel is covered only if its centre (integer coordinates) is; one pixel of margin
        # absorbs float32 rounding on the GPU
        x0 = max(int(np.floor(u.min())) - 1, canvas[0])
        y0 = max(int(np.floor(v.min())) - 1, canvas[1])
        x1 = min(int(np.ceil(u.max())) + 2, canvas[2])
        y1 = min(int(np.ceil(v.max())) + 2, canvas[3])
        if x0 >= x1 or y0 >= y1:
            return None
        return x0, y0, x1, y1

    def _object_alone(self, camera: CameraIR, k: int) -> _ObjectView:
        win = self._window(camera, k)
        if win is None:
            return _ObjectView(0, 0, np.zeros((0, 0), np.float32))
        x0, y0, x1, y1 = win
        return _ObjectView(x0, y0, self._render(camera, [self._object_nodes[k]], x0, y0, x1, y1))

    def _occluder_nodes(self, occluders: str) -> list:
        if occluders == "scene":
            return self._nodes
        if occluders == "objects":
            return self._object_nodes
        raise ValueError(f"occluders must be 'scene' or 'objects', not {occluders!r}")

    # ------------------------------------------------------------------ free space

    def free_distance(self, position, size: int = 16) -> float:
        """Distance (m) from ``position`` to the nearest scene surface, seen along the six axis
        directions (90-degree views of a cube map, ``size`` pixels a side, both faces of every
        triangle drawn). Inside a closed wall, a cupboard or an object this is at most its
        half-thickness; in a room, the distance to the nearest wall, floor or furniture."""
        self._require_scene()
        f = size / 2.0
        K = np.array([[f, 0.0, (size - 1) / 2.0], [0.0, f, (size - 1) / 2.0], [0.0, 0.0, 1.0]])
        rays = np.stack(np.meshgrid((np.arange(size) - (size - 1) / 2.0) / f, (np.arange(size) - (size - 1) / 2.0) / f), -1)
        stretch = np.sqrt(1.0 + (rays ** 2).sum(-1))  # z-depth -> distance along the ray
        p = np.asarray(position, dtype=np.float64)
        self._camera.znear, self._camera.zfar, self._camera.K = 0.001, 100.0, K
        self._renderer.viewport_width = self._renderer.viewport_height = size
        everything = {n: (255, 255, 255) for n in self._nodes}
        nearest = np.inf
        for R in _CUBE_FACES:
            self._pscene.set_pose(self._camera_node, opencv_to_opengl_c2w(cam_to_world(R, -R @ p)))
            z = np.asarray(self._renderer.render(self._pscene, self._flags, seg_node_map=everything), np.float64)
            hit = z > 0
            if hit.any():
                nearest = min(nearest, float((z * stretch)[hit].min()))
        self._factor_key = None  # the main camera is set anew by the next _set_camera
        return nearest

    def near_share(self, camera: CameraIR, near: float, step: int = 8) -> float:
        """Share of the image whose scene depth (along the optical axis) is under ``near`` metres,
        from a depth render at 1/``step`` of the image's size (pinhole: a coarse look at what fills
        the view, not a label)."""
        self._require_scene()
        self._set_camera(camera)
        w, h = max(1, self.width // step), max(1, self.height // step)
        sx, sy = w / self.width, h / self.height
        K = camera.K_array.copy()
        # Pixel centres at integer coordinates: a scaled image's centre c' = (c + 0.5) s - 0.5.
        K[0, :] *= sx
        K[1, :] *= sy
        K[0, 2] += 0.5 * sx - 0.5
        K[1, 2] += 0.5 * sy - 0.5
        depth = self._depth(K, w, h, self._nodes)
        return float(np.count_nonzero((depth > 0) & (depth < near)) / depth.size)

    # ------------------------------------------------------------------ API

    def visib_fract(self, camera: CameraIR, inst: int, delta: float) -> float:
        """Visible fraction of object ``inst`` (gt index) with the whole scene as occluder.

        Same number as ``annotate(camera, delta).instances[inst].visib_fract``, for two renders
        restricted to the object's window.
        """
        self._require_scene()
        if inst not in self._by_inst:
            raise KeyError(f"no object with inst={inst} in the loaded scene")
        self._set_camera(camera)
        obj = self._object_alone(camera, self._by_inst[inst])
        roi = obj.in_image(self.width, self.height) if obj.depth.size else None
        if roi is None or not (obj.depth > 0).any():
            return 0.0
        ix0, iy0, ix1, iy1 = roi
        scene_depth = self._render(camera, self._nodes, ix0, iy0, ix1, iy1)
        info = _gt_info(obj, scene_depth, ix0, iy0, self._factor, self.width, self.height, delta, False)
        return info.visib_fract

    def annotate(
        self, camera: CameraIR, delta: float, occluders: Literal["scene", "objects"] = "scene",
        scene_depth: np.ndarray | None = None,
    ) -> Annotation:
        """Every object's BOP numbers and masks. The occluders' depth is rendered from the loaded
        scene (``occluders``) unless ``scene_depth`` (HxW z-depth in metres, 0 = no measurement)
        gives it, as a real RGB-D image's depth does for BOP's ``calc_gt_info``."""
        self._require_scene()
        self._set_camera(camera)
        W, H = self.width, self.height
        if scene_depth is None:
            depth = self._render(camera, self._occluder_nodes(occluders), 0, 0, W, H)
        else:
            depth = np.asarray(scene_depth, np.float32)
            if depth.shape != (H, W):
                raise ValueError(f"scene depth is {depth.shape[1]}x{depth.shape[0]}, annotator is {W}x{H}")
        T_w2c = camera.T_w2c
        instances, masks, masks_visib = [], [], []
        for k, obj in enumerate(self._objects):
            view = self._object_alone(camera, k)
            info = _gt_info(view, depth, 0, 0, self._factor, W, H, delta, True)
            R, t = model_to_camera(T_w2c, obj.matrix)
            instances.append(
                InstanceGT(
                    obj_id=int(obj.obj_id),
                    inst=int(obj.inst),
                    R_m2c=[[float(x) for x in row] for row in R],
                    t_m2c=[float(x) for x in t],
                    bbox_obj=info.bbox_obj,
                    bbox_visib=info.bbox_visib,
                    px_count_all=info.px_count_all,
                    px_count_valid=info.px_count_valid,
                    px_count_visib=info.px_count_visib,
                    visib_fract=float(info.visib_fract),
                )
            )
            masks.append(info.mask)
            masks_visib.append(info.mask_visib)
        return Annotation(instances=instances, masks=masks, masks_visib=masks_visib, depth=depth)

    def annotate_lens(self, camera: CameraIR, warp, k, delta: float,
                      occluders: Literal["scene", "objects"] = "scene") -> Annotation:
        """:meth:`annotate` for the image of ``camera`` seen through lens distortion ``k`` (see
        :mod:`.lens`): masks, depth and visible counts are the pinhole renders looked up at every
        distorted pixel's ray (nearest); ``px_count_all`` and ``bbox_obj`` follow the amodal
        silhouette through the distortion, beyond the image up to where the model stays monotonic."""
        self._require_scene()
        look = self._lens_lookup(camera, warp, k, self._occluder_nodes(occluders))
        instances, masks, masks_visib = [], [], []
        for n, obj in enumerate(self._objects):
            m, visib, px_all, bbox_obj = self._through_lens(camera, n, look, delta)
            px_visib = int(np.count_nonzero(visib))
            R, t = model_to_camera(camera.T_w2c, obj.matrix)
            instances.append(InstanceGT(
                obj_id=int(obj.obj_id), inst=int(obj.inst), R_m2c=[[float(x) for x in row] for row in R],
                t_m2c=[float(x) for x in t], bbox_obj=bbox_obj if px_visib else list(EMPTY_BBOX),
                bbox_visib=bbox_from_mask(visib) if px_visib else list(EMPTY_BBOX), px_count_all=px_all,
                px_count_valid=int(np.count_nonzero(m & (look["dist_scene"] > 0))), px_count_visib=px_visib,
                visib_fract=float(px_visib / px_all) if px_all else 0.0))
            masks.append(m)
            masks_visib.append(visib)
        return Annotation(instances=instances, masks=masks, masks_visib=masks_visib, depth=look["depth"])

    def visib_fract_lens(self, camera: CameraIR, warp, k, inst: int, delta: float) -> float:
        """:meth:`visib_fract` through the lens: the same number as :meth:`annotate_lens` gives."""
        self._require_scene()
        if inst not in self._by_inst:
            raise KeyError(f"no object with inst={inst} in the loaded scene")
        look = self._lens_lookup(camera, warp, k, self._nodes)
        _, visib, px_all, _ = self._through_lens(camera, self._by_inst[inst], look, delta)
        return float(np.count_nonzero(visib) / px_all) if px_all else 0.0

    def _lens_lookup(self, camera: CameraIR, warp, k, nodes) -> dict:
        """The scene's depth through the lens and what every object's lookup shares."""
        from ..model import lens

        self._set_camera(camera)
        win = self._render(camera, nodes, warp.x0, warp.y0, warp.x0 + warp.width, warp.y0 + warp.height)
        depth = lens.remap_nearest(win, warp)
        factor = np.sqrt((warp.rays ** 2).sum(axis=-1) + 1.0)
        return {"depth": depth, "factor": factor, "dist_scene": (depth * factor).astype(np.float32), "warp": warp,
                "k": k, "r_limit": lens.monotonic_radius(k, float(np.linalg.norm(warp.rays, axis=-1).max()))}

    def _through_lens(self, camera: CameraIR, n: int, look: dict, delta: float):
        """Object ``n`` through the lens: (amodal mask, visible mask, px_count_all, bbox_obj)."""
        from ..model import lens

        warp = look["warp"]
        view = self._object_alone(camera, n)
        u, v = warp.map_u + warp.x0 - view.x0, warp.map_v + warp.y0 - view.y0  # into the object's window
        d_obj = lens.sample_nearest(view.depth, u, v) if view.depth.size else np.zeros_like(look["depth"])
        dist_obj = (d_obj * look["factor"]).astype(np.float32)
        m = dist_obj > 0
        dist_scene = look["dist_scene"]
        visib = m & ((dist_obj - dist_scene <= np.float32(delta)) | (dist_scene == 0))
        ys, xs = np.nonzero(view.depth > 0)
        pix, area = lens.distorted_silhouette(camera.K_array, np.stack([xs + view.x0, ys + view.y0], -1).astype(np.float64),
                                              look["k"], look["r_limit"])
        px_all = max(int(round(float(area.sum()))), int(np.count_nonzero(m)))
        bbox_obj = list(EMPTY_BBOX)
        if len(pix):
            lo, hi = np.rint(pix.min(axis=0)).astype(int), np.rint(pix.max(axis=0)).astype(int)
            bbox_obj = [int(lo[0]), int(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1])]
        return m, visib, px_all, bbox_obj

    def close(self) -> None:
        if self._renderer is not None:
            # Not OffscreenRenderer.delete(): it terminates the EGL display every other renderer
            # in this process (a backend's) shares.
            glutil.release_renderer(self._renderer)
            self._renderer = None

    def __enter__(self) -> "Annotator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

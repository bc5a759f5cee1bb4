"""Checks of the PBR material channels a backend declares (``Capabilities.material_channels``).

Each channel's map is rendered for real, at 24 x 24 pixels, and must change the image the way its
values say: a normal map turns the shading towards its vectors, a roughness map sharpens a
highlight, an emission map lights the floor, an opacity map cuts holes the annotation engine sees
too. A check of a channel the backend does not declare raises ``NotDeclared``. They run on a
``ConformanceContext`` (its backend instance is shared with the conformance checks); the base
class ``specsynth.testing.suite.MaterialChannelTests`` makes them pytest tests.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from PIL import Image

from ..assets.meshio import MeshData, write_mesh
from ..model.colour import srgb_to_linear
from ..model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from ..spec.models import QualityPreset
from ..views.cameras import look_at
from .conformance import ConformanceContext, NotDeclared, _require

SIZE = 24  # pixels, square
BLACK = WorldIR(color=(0.0, 0.0, 0.0))


def quad(folder: Path, name: str, half: float, z: float = 0.0) -> MeshInstance:
    """A square of side 2 ``half`` in the plane z, facing +Z, UVs over [0, 1]^2, at the origin."""
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float32)
    mesh = MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                    normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
                    uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32))
    key = f"{name}_{half:g}_{z:g}"  # backends cache meshes by key: one key, one geometry
    path = Path(folder) / f"{key}.ply"
    write_mesh(path, mesh)
    return MeshInstance(name, str(path), key, as_tuple(np.eye(4)), MaterialIR())


def png(folder: Path, name: str, array: np.ndarray) -> str:
    path = Path(folder) / f"{name}.png"
    Image.fromarray(array.astype(np.uint8)).save(path)
    return str(path)


def camera(eye, target, f: float, width: int = SIZE, height: int = SIZE, up=(0.0, 0.0, 1.0)) -> CameraIR:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), up=up)
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    return CameraIR(K=as_tuple(K), width=width, height=height, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def quality(spp: int, depth: int = 2) -> QualityPreset:
    return QualityPreset(aa=spp, diffuse_rays=1, specular_rays=1, diffuse_depth=depth, specular_depth=depth,
                         max_depth=depth)


def sun(direction_to_sun) -> LightIR:
    """A sun shining from ``direction_to_sun`` (lights emit along their local -Z)."""
    z = np.asarray(direction_to_sun, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.99 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    return LightIR(kind="sun", pose=as_tuple(T), power=3.0, sun_angle=1.0)


TOP_DOWN = camera((0, 0, 3.0), (0, 0.001, 0), 40.0, up=(0, 1, 0))


def _luminance(ctx: ConformanceContext, meshes, lights=(), world=BLACK, cam=TOP_DOWN, spp=16, depth=2) -> np.ndarray:
    """Mean linear radiance over the channels, per pixel (decoded from sRGB if the backend gives no linear)."""
    ctx.load(RenderScene(meshes=tuple(meshes), lights=tuple(lights), world=world))
    res = ctx.backend.render(cam, quality(spp, depth), 3)
    lin = res.linear if res.linear is not None else srgb_to_linear(res.rgb / 255.0)
    return np.asarray(lin, np.float64).mean(axis=2)


def _folder(ctx: ConformanceContext) -> Path:
    folder = ctx.tmp_path / "materials"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _with(mesh: MeshInstance, material: MaterialIR, pose=None, **ids) -> MeshInstance:
    return replace(mesh, material=material, **({"pose": pose} if pose is not None else {}), **ids)


def require_channel(ctx: ConformanceContext, channel: str) -> None:
    if channel not in ctx.plugin.capabilities.material_channels:
        raise NotDeclared(f"{ctx.name} does not declare the material channel {channel!r}")


def check_normal_map(ctx: ConformanceContext, axis: int) -> None:
    """A normal map tilted towards the sun brightens a plane, tilted away darkens it; ``axis`` 0:
    red = +u = +x, 1: green = +v = +y (OpenGL normal maps)."""
    require_channel(ctx, "normal")
    folder = _folder(ctx)
    plane = quad(folder, "plane", 1.0)
    sun_dir = [0.0, 0.0, 0.6]
    sun_dir[axis] = 1.0
    lum = {}
    for name, tilt in (("flat", 0.0), ("toward", 0.6), ("away", -0.6)):
        n = np.array([0.0, 0.0, 1.0])
        n[axis] = tilt
        n /= np.linalg.norm(n)
        texture = png(folder, f"normal_{axis}_{tilt}", np.tile(np.rint((n * 0.5 + 0.5) * 255), (8, 8, 1)))
        mat = MaterialIR(base_color=(0.6,) * 3, specular=0.0, roughness=1.0, use_vertex_colors=False,
                         normal_texture=None if name == "flat" else texture)
        lum[name] = float(_luminance(ctx, [_with(plane, mat)], [sun(sun_dir)])[8:16, 8:16].mean())
    _require(lum["toward"] > 1.15 * lum["flat"] > 1.15 * 1.15 * lum["away"], ctx.name,
             f"a normal map along {'xy'[axis]} does not turn the shading towards its vectors: {lum}")


def check_roughness_map(ctx: ConformanceContext) -> None:
    """A roughness map of 0.1 gives a highlight over three times brighter than one of 0.9."""
    require_channel(ctx, "roughness")
    folder = _folder(ctx)
    plane = quad(folder, "plane", 1.0)
    light = LightIR(kind="point", power=40.0,
                    pose=as_tuple(np.array([[1, 0, 0, -0.6], [0, 1, 0, 0], [0, 0, 1, 1.2], [0, 0, 0, 1]], float)))
    cam = camera((0.6, 0, 1.2), (0, 0, 0), 40.0)  # in the light's mirror direction
    peaks = {}
    for r in (0.1, 0.9):
        mat = MaterialIR(base_color=(0.2,) * 3, roughness=0.5, specular=1.0, use_vertex_colors=False,
                         roughness_texture=png(folder, f"roughness_{r}", np.full((8, 8), round(r * 255))))
        peaks[r] = float(_luminance(ctx, [_with(plane, mat)], [light], cam=cam, spp=32).max())
    _require(peaks[0.1] > 3.0 * peaks[0.9], ctx.name, f"a roughness map does not sharpen the highlight: {peaks}")


def check_emission_map(ctx: ConformanceContext) -> None:
    """A lamp whose emission map is white lights the floor under it; one whose map is black does not."""
    require_channel(ctx, "emission")
    folder = _folder(ctx)
    floor = _with(quad(folder, "floor", 1.5), MaterialIR(base_color=(0.8,) * 3, specular=0.0, roughness=1.0,
                                                           use_vertex_colors=False))
    T = np.diag([1.0, -1.0, -1.0, 1.0])  # the lamp faces down, at the floor
    T[:3, 3] = (0.0, 0.0, 0.5)
    floor_pixels = {}
    for name, value in (("white", 255), ("black", 0)):
        lamp_mat = MaterialIR(base_color=(0.0,) * 3, specular=0.0, use_vertex_colors=False, emission=(4.0, 4.0, 4.0),
                              emission_texture=png(folder, f"emission_{name}", np.full((8, 8, 3), value)))
        lamp = _with(quad(folder, "lamp", 0.2), lamp_mat, pose=as_tuple(T))
        img = _luminance(ctx, [floor, lamp], cam=camera((1.2, -1.2, 1.2), (0, 0, 0), 20.0), spp=32)
        floor_pixels[name] = float(np.median(img))  # most pixels are floor, lit by the lamp alone
    _require(floor_pixels["white"] > 0.005 and floor_pixels["black"] < 0.0005, ctx.name,
             f"an emission map does not decide how much the lamp lights the floor: {floor_pixels}")


def check_opacity_map(ctx: ConformanceContext) -> None:
    """A card, opaque on its left half only (an alpha mask), in front of a red object: the image
    shows the object through the right half, and the annotation engine sees it there too."""
    from ..annotate.engine import Annotator

    require_channel(ctx, "opacity")
    folder = _folder(ctx)
    obj = _with(quad(folder, "obj", 0.5), MaterialIR(base_color=(0.9, 0.1, 0.1), specular=0.0,
                                                        use_vertex_colors=False), obj_id=1, inst=0)
    coverage = np.zeros((8, 8), np.uint8)
    coverage[:, :4] = 255  # u < 0.5 opaque
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 0.4)
    card_mat = MaterialIR(base_color=(0.1, 0.1, 0.9), specular=0.0, use_vertex_colors=False, alpha_mode="mask",
                          opacity_texture=png(folder, "coverage", coverage))
    card = _with(quad(folder, "card", 0.8), card_mat, pose=as_tuple(T))
    scene = RenderScene(meshes=(obj, card), world=WorldIR(color=(1.0, 1.0, 1.0)))
    ctx.load(scene)
    res = ctx.backend.render(TOP_DOWN, quality(16), 3)
    rgb = res.linear if res.linear is not None else srgb_to_linear(res.rgb / 255.0)
    ann = Annotator(SIZE, SIZE)
    try:
        ann.load(scene)
        a = ann.annotate(TOP_DOWN, delta=0.005)
    finally:
        ann.close()
    full, visib = a.masks[0], a.masks_visib[0]
    cols = np.nonzero(full.any(0))[0]
    _require(len(cols) > 6, ctx.name, "test setup: the object covers too few columns")
    left, right = cols[: len(cols) // 2 - 1], cols[len(cols) // 2 + 1:]
    # Image x grows with world x here; u grows with x: the card hides the object's left half only.
    _require(not visib[:, left].any() and visib[:, right][full[:, right]].all(), ctx.name,
             "the annotation engine (not the backend) does not see the object through the card's clear half only")
    red = rgb[..., 0] > 2 * rgb[..., 2]
    blue = rgb[..., 2] > 2 * rgb[..., 0]
    shown, hidden = red[:, right][full[:, right]].mean(), blue[:, left][full[:, left]].mean()
    _require(shown > 0.9 and hidden > 0.9, ctx.name,
             f"an opacity map does not cut the card where it is clear: {shown:.0%} of the object shows through "
             f"the clear half, {hidden:.0%} of the opaque half is the card's colour")

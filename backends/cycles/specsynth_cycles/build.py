"""Building Blender data-blocks from the scene IR. Every function takes ``bpy`` explicitly: the module
itself imports no renderer, so the core can import the package without Blender installed."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from specsynth.assets.meshio import MeshData, read_mesh
from specsynth.model.ir import IDENTITY_UV, LightIR, MaterialIR, MeshInstance, WorldIR

COLOR_ATTR = "Col"
MAX_ENV_MAP_RESOLUTION = 1024
SKY_AZIMUTH_SIGN = -1.0  # IR sun azimuth (counter-clockwise from +Y) -> Blender's sun_rotation
UV_LAYER = "UVMap"


def build_mesh(bpy, name: str, data: MeshData):
    """Mesh data-block from the normalised arrays; foreach_set keeps big BOP meshes fast."""
    v = np.ascontiguousarray(data.vertices, dtype=np.float32)
    f = np.ascontiguousarray(data.faces, dtype=np.int32)
    # A triangle naming one vertex twice (zero area, met in library furniture) is an invalid
    # polygon to Blender, and setting custom normals on such a mesh crashes it.
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    nv, nf = len(v), len(f)
    me = bpy.data.meshes.new(name)
    me.vertices.add(nv)
    me.vertices.foreach_set("co", v.ravel())
    me.loops.add(3 * nf)
    me.loops.foreach_set("vertex_index", f.ravel())
    me.polygons.add(nf)
    me.polygons.foreach_set("loop_start", np.arange(0, 3 * nf, 3, dtype=np.int32))
    if data.uv is not None:
        uv = me.uv_layers.new(name=UV_LAYER)
        uv.data.foreach_set("uv", np.ascontiguousarray(data.uv[f.ravel()], dtype=np.float32).ravel())
    if data.colors is not None:
        # BYTE_COLOR holds sRGB-encoded bytes; the Color Attribute node returns them linearised.
        attr = me.color_attributes.new(COLOR_ATTR, "BYTE_COLOR", "POINT")
        attr.data.foreach_set("color_srgb", (data.colors.astype(np.float32) / 255.0).ravel())
    me.update()
    if data.normals is not None:
        # The file's normals are the shading normals every backend (and the annotator) uses.
        me.polygons.foreach_set("use_smooth", np.ones(nf, dtype=bool))
        n = np.asarray(data.normals, dtype=np.float64)
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        me.normals_split_custom_set_from_vertices(n.astype(np.float32))
    me.update()
    return me


def _link(nt, a, b):
    nt.links.new(a, b)


_EXTENSION = {"repeat": "REPEAT", "clamp": "EXTEND", "mirror": "MIRROR"}


class _Nodes:
    """Node-building helpers for one material: every image shares one UV input (after the
    material's uv_transform) and its wrap mode."""

    def __init__(self, bpy, nt, m: MaterialIR):
        self.bpy, self.nt, self.m = bpy, nt, m
        self._uv = None

    def new(self, kind: str, **attrs):
        node = self.nt.nodes.new(kind)
        for k, v in attrs.items():
            setattr(node, k, v)
        return node

    def uv(self):
        """UV socket, transformed: u' = a u + b v + c, v' = d u + e v + f (IR convention)."""
        if self._uv is not None:
            return self._uv
        uvn = self.new("ShaderNodeUVMap", uv_map=UV_LAYER)
        out = uvn.outputs["UV"]
        if tuple(self.m.uv_transform) != IDENTITY_UV:
            a, b, c, d, e, f = self.m.uv_transform
            comb = self.new("ShaderNodeCombineXYZ")
            for row, (x, y, t) in enumerate(((a, b, c), (d, e, f))):
                dot = self.new("ShaderNodeVectorMath", operation="DOT_PRODUCT")
                dot.inputs[1].default_value = (x, y, 0.0)
                _link(self.nt, out, dot.inputs[0])
                add = self.new("ShaderNodeMath", operation="ADD")
                add.inputs[1].default_value = t
                _link(self.nt, dot.outputs["Value"], add.inputs[0])
                _link(self.nt, add.outputs[0], comb.inputs[row])
            out = comb.outputs["Vector"]
        self._uv = out
        return out

    def image(self, path: str, colour: bool, closest: bool = False):
        img = self.bpy.data.images.load(str(Path(path)), check_existing=True)
        img.colorspace_settings.name = "sRGB" if colour else "Non-Color"
        tex = self.new("ShaderNodeTexImage", image=img, interpolation="Closest" if closest else "Linear",
                       extension=_EXTENSION[self.m.wrap])
        _link(self.nt, self.uv(), tex.inputs["Vector"])
        return tex

    def multiply(self, a, b):
        mul = self.new("ShaderNodeVectorMath", operation="MULTIPLY")
        _link(self.nt, a, mul.inputs[0])
        _link(self.nt, b, mul.inputs[1])
        return mul.outputs["Vector"]

    def constant(self, rgb):
        const = self.new("ShaderNodeRGB")
        const.outputs[0].default_value = (*rgb, 1.0)
        return const.outputs[0]


def build_material(bpy, name: str, m: MaterialIR, *, has_colors: bool, has_uv: bool):
    mat = bpy.data.materials.new(name)
    nt = mat.node_tree
    if nt is None:  # Blender < 5 needs node trees switched on explicitly
        mat.use_nodes = True
        nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeBsdfPrincipled")
    inp = bsdf.inputs
    inp["Roughness"].default_value = float(m.roughness)
    inp["Metallic"].default_value = float(m.metallic)
    inp["Specular IOR Level"].default_value = float(m.specular)
    inp["Transmission Weight"].default_value = float(m.transmission)
    if m.textures and not has_uv:
        raise ValueError(f"cycles: material of {name!r} has a texture but its mesh has no UVs")
    nodes = _Nodes(bpy, nt, m)
    _base_colour(nodes, inp, m, has_colors)
    if m.roughness_texture:
        _link(nt, nodes.image(m.roughness_texture, colour=False).outputs["Color"], inp["Roughness"])
    if m.metallic_texture:
        _link(nt, nodes.image(m.metallic_texture, colour=False).outputs["Color"], inp["Metallic"])
    if m.normal_texture:
        nmap = nodes.new("ShaderNodeNormalMap", space="TANGENT", uv_map=UV_LAYER)
        nmap.inputs["Strength"].default_value = 1.0  # the scale is baked into the map (glTF's rule)
        _link(nt, nodes.image(m.normal_texture, colour=False).outputs["Color"], nmap.inputs["Color"])
        _link(nt, nmap.outputs["Normal"], inp["Normal"])
    _emission(nodes, inp, m)
    if m.transparent:
        if m.opacity_texture:
            tex = nodes.image(m.opacity_texture, colour=False, closest=m.alpha_mode == "mask")
            _link(nt, tex.outputs["Color"], inp["Alpha"])
        else:
            inp["Alpha"].default_value = float(m.opacity)
    return mat


def _base_colour(nodes: _Nodes, inp, m: MaterialIR, has_colors: bool) -> None:
    """Base colour = constant x vertex colour x texture; vector math, so nothing is clamped."""
    factors = []
    if m.use_vertex_colors and has_colors:
        factors.append(nodes.new("ShaderNodeVertexColor", layer_name=COLOR_ATTR).outputs["Color"])
    if m.texture:
        factors.append(nodes.image(m.texture, colour=True).outputs["Color"])
    if not factors:
        inp["Base Color"].default_value = (*m.base_color, 1.0)
        return
    out = nodes.constant(m.base_color)
    for fac in factors:
        out = nodes.multiply(out, fac)
    _link(nodes.nt, out, inp["Base Color"])


def _emission(nodes: _Nodes, inp, m: MaterialIR) -> None:
    if not any(c > 0 for c in m.emission):
        inp["Emission Strength"].default_value = 0.0
        return
    inp["Emission Strength"].default_value = 1.0  # strength 1: the colour is the radiance
    if m.emission_texture:
        out = nodes.multiply(nodes.constant(m.emission), nodes.image(m.emission_texture, colour=True).outputs["Color"])
        _link(nodes.nt, out, inp["Emission Color"])
    else:
        inp["Emission Color"].default_value = (*m.emission, 1.0)


def build_meshes(bpy, collection, meshes: tuple[MeshInstance, ...]) -> list:
    """Objects for all mesh instances; mesh data shared by mesh_key, materials shared when equal."""
    from mathutils import Matrix

    mesh_cache: dict[str, tuple] = {}
    mat_cache: dict[tuple, object] = {}
    objs = []
    for i, inst in enumerate(meshes):
        if inst.mesh_key not in mesh_cache:
            data = read_mesh(inst.mesh_path).validate(inst.mesh_path)
            me = build_mesh(bpy, f"m{len(mesh_cache)}", data)
            me.materials.append(None)  # one slot, filled per object
            mesh_cache[inst.mesh_key] = (me, data.colors is not None, data.uv is not None)
        me, has_colors, has_uv = mesh_cache[inst.mesh_key]
        mkey = (inst.material, has_colors and inst.material.use_vertex_colors, has_uv and bool(inst.material.textures))
        if mkey not in mat_cache:
            mat_cache[mkey] = build_material(bpy, f"mat{len(mat_cache)}", inst.material, has_colors=has_colors, has_uv=has_uv)
        ob = bpy.data.objects.new(f"o{i}", me)
        collection.objects.link(ob)
        ob.matrix_world = Matrix(inst.matrix.tolist())
        # Object-linked material: instances sharing a mesh may differ in material.
        ob.material_slots[0].link = "OBJECT"
        ob.material_slots[0].material = mat_cache[mkey]
        # Mask renders read this back; 0 marks scene geometry (background in the mask).
        ob.pass_index = inst.inst + 1 if inst.is_object and inst.inst is not None else 0
        objs.append(ob)
    return objs


def build_light(bpy, collection, i: int, light: LightIR):
    from mathutils import Matrix

    kind = {"area": "AREA", "point": "POINT", "spot": "SPOT", "sun": "SUN"}[light.kind]
    ld = bpy.data.lights.new(f"l{i}", kind)
    ld.color = tuple(float(c) for c in light.color)
    # Blender's units are the IR's: watts for area/point/spot, W/m^2 irradiance for sun.
    ld.energy = float(light.power)
    if kind == "AREA":
        ld.shape = "RECTANGLE"
        ld.size, ld.size_y = float(light.size[0]), float(light.size[1])
    elif kind in ("POINT", "SPOT"):
        # The IR's point and spot lights are ideal (zero radius), like the other backends'.
        ld.shadow_soft_size = 0.0
        if kind == "SPOT":
            ld.spot_size = math.radians(light.spot_angle)
            ld.spot_blend = float(light.spot_blend)
    else:
        ld.angle = math.radians(light.sun_angle)
    ob = bpy.data.objects.new(f"l{i}", ld)
    if kind == "AREA":
        # A camera sees a ceiling panel; Blender hides lights from camera rays by default, while
        # Mitsuba's rectangle emitter is seen (measured: a hidden panel made Cycles 1.2-3.5x
        # darker than Mitsuba per light in the kiva scene).
        ob.visible_camera = True
    collection.objects.link(ob)
    ob.matrix_world = Matrix(light.matrix.tolist())  # both emit along local -Z
    return ob


def build_world(bpy, world: WorldIR):
    w = bpy.data.worlds.new("world")
    nt = w.node_tree
    if nt is None:
        w.use_nodes = True
        nt = w.node_tree
    bg = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Strength"].default_value = float(world.strength)
    if world.kind == "color":
        bg.inputs["Color"].default_value = (*world.color, 1.0)
    elif world.kind == "envmap":
        if not world.envmap:
            raise ValueError("cycles: world kind 'envmap' needs an envmap file")
        env = nt.nodes.new("ShaderNodeTexEnvironment")
        env.image = bpy.data.images.load(str(Path(world.envmap)), check_existing=True)
        env.interpolation = "Linear"
        # Cycles rebuilds the importance map on every render (no persistent data): AUTOMATIC took
        # 5-8 s per render for a 1024x512 HDRI, a manual map at the image's width ~0.3-0.5 s.
        w.cycles.sampling_method = "MANUAL"
        w.cycles.sample_map_resolution = int(min(max(env.image.size[0], 64), MAX_ENV_MAP_RESOLUTION))
        coord = nt.nodes.new("ShaderNodeTexCoord")
        mapping = nt.nodes.new("ShaderNodeMapping")
        # Rotating the environment by +theta means looking it up at direction R(-theta) d.
        mapping.inputs["Rotation"].default_value = (0.0, 0.0, -math.radians(world.rotation_z))
        nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
        nt.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
        nt.links.new(env.outputs["Color"], bg.inputs["Color"])
    elif world.kind == "sky":
        sky = nt.nodes.new("ShaderNodeTexSky")
        types = {i.identifier for i in sky.bl_rna.properties["sky_type"].enum_items}
        # 5.0 renamed Nishita to SINGLE_SCATTERING (legacy) and added its successor MULTIPLE_SCATTERING.
        for t in ("MULTIPLE_SCATTERING", "SINGLE_SCATTERING", "NISHITA"):
            if t in types:
                sky.sky_type = t
                break
        sky.sun_elevation = math.radians(world.sun_elevation)
        # Blender turns the sun clockwise seen from above (rotation 90 deg puts it towards +X,
        # measured); the IR's azimuth turns counter-clockwise (90 deg -> -X), as Mitsuba's does.
        sky.sun_rotation = SKY_AZIMUTH_SIGN * math.radians(world.sun_azimuth)
        # The sun itself is a LightIR sun in the scene; a disc here would light everything twice.
        if hasattr(sky, "sun_disc"):
            sky.sun_disc = False
        # The scattering models have no turbidity; aerosol density is its nearest knob
        # (turbidity 1 = pure air -> 0, turbidity 3 = clear day -> 1, Blender's "clear day" value).
        dens = max(0.0, (world.turbidity - 1.0) / 2.0)
        for attr in ("aerosol_density", "dust_density"):
            if hasattr(sky, attr):
                setattr(sky, attr, min(dens, 10.0))
                break
        if hasattr(sky, "turbidity"):
            sky.turbidity = float(world.turbidity)
        nt.links.new(sky.outputs["Color"], bg.inputs["Color"])
    else:
        raise ValueError(f"cycles: unknown world kind {world.kind!r}")
    return w


def build_mask_material(bpy):
    """Emission = object pass index: a 1-spp, 0-bounce render then reads instance ids back exactly."""
    mat = bpy.data.materials.new("__specsynth_mask")
    mat.use_fake_user = True
    nt = mat.node_tree
    if nt is None:
        mat.use_nodes = True
        nt = mat.node_tree
    for n in list(nt.nodes):
        nt.nodes.remove(n)
    info = nt.nodes.new("ShaderNodeObjectInfo")
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    nt.links.new(info.outputs["Object Index"], em.inputs["Strength"])
    nt.links.new(em.outputs["Emission"], out.inputs["Surface"])
    return mat


def build_mask_world(bpy):
    w = bpy.data.worlds.new("__specsynth_mask_world")
    w.use_fake_user = True
    nt = w.node_tree
    if nt is None:
        w.use_nodes = True
        nt = w.node_tree
    bg = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bg.inputs["Strength"].default_value = 0.0
    return w

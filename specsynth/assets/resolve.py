"""Asset resolution: BOP model folders, mesh files, pybullet_data built-ins, bundled HDRIs.

Everything is converted once into the normalised form of ``specsynth.assets.meshio`` (metres) and cached
by content hash under ``<cache>/assets/``; backends and the annotation engine read only that form.
No network, ever: BOP models come from a folder the user downloaded, built-ins from the
``pybullet_data`` package, HDRIs from the library (``library/hdris.py``).

The compile path calls :func:`object_fingerprints` (hashes of source bytes, no mesh parsing) and
:func:`object_size_problems` (a user's mesh file parsed once for its size, cached by its bytes), so
heavy imports (trimesh, PIL) happen inside the conversion functions.
"""

from __future__ import annotations

import difflib
import functools
import hashlib
import importlib.util
import itertools
import json
import math
import os
import re
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_write_bytes
from ..files import not_a_file
from ..model.colour import linear_to_srgb, srgb_to_linear
from ..model.conventions import rpy_matrix
from ..model.ir import MaterialIR
from ..spec import models as spec_mod
from . import bopmodels
from .library import realsets
from .library.cache import cache_dir
from .library.hdris import (  # noqa: F401  (builtin_hdris re-exported)
    SOURCE as HDRI_SOURCE,
)
from .library.hdris import (
    builtin_hdris,
    studiolights_dir,
)
from .meshfiles import bake, ply, single
from .meshfiles import gltf as gltf_reader
from .meshfiles import obj as obj_reader
from .meshfiles import urdf as urdf_reader
from .meshfiles.part import MeshFileError, read_file, referenced_file
from .meshfiles.sniff import check_mesh_file
from .meshio import MeshData, MeshFormatError, mesh_bytes
from .repair import drop_overlapping

# Bump when the conversion changes its output for the same input: every cached mesh and every
# content key that depends on an asset then changes with it.
# 2: textures are copied into the cache under their content hash (no path into a user's folder).
# 3 (4): faces wound the way their normals point; zero-length or non-finite normals replaced by their faces'.
# 5 (6): faces whose corner normals point away from them drawn flat; faces overlapping a larger
# one in its plane dropped (assets/repair.py).
# 7: broken texture coordinates replaced by their neighbours' (meshio.UV_LIMIT).
CONVERSION_VERSION = 7

# Built-in models are re-centred on their bounding box, as BOP expects of a model (pybullet_data's
# origins are wherever the modeller left them: 100 mm off for the mug). User models stay as given.
BUILTIN_ORIGIN = "bbox_centre"

UNIT_SCALE = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MIN_DIAMETER = 1e-3  # metres; below this the declared unit is almost surely wrong
MAX_DIAMETER = 10.0

BOP_HELP = (
    "BOP model folders are not bundled: download e.g. lm_models.zip or ruapc_models.zip from the BOP "
    "website (https://bop.felk.cvut.cz/datasets/), unpack it and point 'objects.path' at its models/ "
    "folder (${ENV_VAR} expansion works). specsynth never downloads them."
)


class AssetError(ValueError):
    """A missing, empty, corrupt or absurd asset; the message names the asset, and ``field`` the spec
    field that named it where the raiser knows it (so the spec's line can be shown)."""

    def __init__(self, message: str, field: str | None = None):
        super().__init__(message)
        self.field = field


@dataclass(frozen=True)
class ObjectAsset:
    obj_id: int
    name: str  # built-in name, or obj_XXXXXX for BOP/mesh objects
    mesh_path: str  # normalised PLY, metres
    mesh_key: str  # content hash of the normalised mesh
    material: MaterialIR
    diameter: float  # metres, max distance between two vertices (BOP definition)
    bbox_min: tuple[float, float, float]  # metres, model frame
    extents: tuple[float, float, float]  # metres, bounding-box size
    source: str  # where it came from (path or 'pybullet_data:duck')

    @property
    def credit(self) -> dict[str, str] | None:
        """Attribution of a built-in (third-party) model; a user's own model needs none."""
        if self.source.startswith("furniture:"):
            return _catalogue_item(self.name).credit
        if not self.source.startswith("pybullet_data:"):
            return None
        return {"asset": f"object:{self.name}", "name": self.name, "author": "pybullet_data contributors",
                "copyright": "", "licence": "as distributed with pybullet (zlib licence, see pybullet's LICENSE.txt)",
                "source": f"pybullet_data (PyPI package pybullet), {self.source.split(':', 1)[1]}"}


# --------------------------------------------------------------------------- paths, hashing


@functools.lru_cache(maxsize=8192)
def _digest_of(path: str, mtime_ns: int, size: int) -> str:
    # Keyed on (mtime, size) so an edited file is re-hashed; the key is what makes memoising safe.
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def file_digest(path: Path, what: str | None = None) -> str:
    """sha256 of a file's bytes, memoised by (path, mtime, size); only a regular file is opened."""
    require_file(path, what)
    st = os.stat(path)
    return _digest_of(str(Path(path).resolve()), st.st_mtime_ns, st.st_size)


def require_file(path: Path, what: str | None = None) -> None:
    """AssetError naming ``path`` and what it is (missing, a folder, a FIFO, a device) unless it is
    a regular file: checked before anything opens it, which would hang on a FIFO or /dev/zero."""
    problem = not_a_file(path)
    if problem == "not found":
        raise AssetError(f"{what or path}: file not found: {path}")
    if problem is not None:
        raise AssetError(f"{what or path}: {path} is {problem}")


def _hash_json(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def expand_path(p: str, base: Path, what: str) -> Path:
    """``${VAR}``/``~`` expansion, then relative to ``base``; an unset variable is an error, not a path.
    ``dataset:NAME/...`` names an installed real set (``library/realsets.py``)."""
    if p.startswith(realsets.PREFIX):
        try:
            return realsets.resolve_ref(p, cache_dir())
        except realsets.RealSetError as e:
            raise AssetError(f"{what}: {e}") from None
    expanded = os.path.expanduser(os.path.expandvars(p))
    left = re.findall(r"\$\{?([A-Za-z_][A-Za-z0-9_]*)", expanded)
    if left:
        raise AssetError(f"{what}: environment variable {left[0]} in {p!r} is not set. {BOP_HELP}")
    q = Path(expanded)
    return q if q.is_absolute() else Path(base) / q


def pybullet_data_root() -> Path:
    # find_spec, not import: pybullet_data is only a folder of files for us.
    s = importlib.util.find_spec("pybullet_data")
    if s is None or not s.submodule_search_locations:
        raise AssetError("pybullet_data is not installed (pip install pybullet); built-in assets need it")
    return Path(list(s.submodule_search_locations)[0])


def resolve_data_ref(ref: str, base: Path, what: str) -> Path:
    """'pybullet_data:table/table.obj' or a path relative to ``base``."""
    if ref.startswith("pybullet_data:"):
        p = pybullet_data_root() / ref.split(":", 1)[1]
    else:
        p = expand_path(ref, base, what)
    require_file(p, what)
    return p


# --------------------------------------------------------------------------- HDRIs


def hdri_path(name: str) -> Path:
    d = studiolights_dir()
    if d is None:
        raise AssetError(f"HDRI {name!r}: the built-in HDRIs come with {HDRI_SOURCE}")
    p = d / f"{name}.exr"
    if not p.is_file():
        raise AssetError(f"HDRI {name!r}: unknown, built-in HDRIs are {', '.join(builtin_hdris())}")
    return p


# --------------------------------------------------------------------------- built-in objects


@dataclass(frozen=True)
class _Builtin:
    urdf: str | None = None  # relative to pybullet_data
    mesh: str | None = None  # used when there is no URDF
    scale: float = 1.0  # only without URDF (a URDF carries its own scale)
    # Extra rotation (rpy, radians) applied after the URDF visual origin, so the asset's up is +Z:
    # several pybullet_data meshes are Y-up OBJs inside URDFs whose origin does not rotate them.
    up_fix: tuple[float, float, float] = (0.0, 0.0, 0.0)
    real_diameter: float | None = None  # rescale to a real-world size (the URDF size is not one)


_Y_UP = (math.pi / 2, 0.0, 0.0)

_BUILTINS: dict[str, _Builtin] = {
    "duck": _Builtin(urdf="duck_vhacd.urdf", up_fix=_Y_UP),
    "teddy": _Builtin(urdf="teddy_vhacd.urdf", up_fix=_Y_UP),
    "mug": _Builtin(urdf="objects/mug.urdf"),
    "lego": _Builtin(urdf="lego/lego.urdf"),
    "jenga": _Builtin(urdf="jenga/jenga.urdf"),
    # 1.5 units wide and no URDF: 0.1 makes it a 15 cm ring.
    "torus": _Builtin(mesh="torus/torus_textured.obj", scale=0.1, up_fix=_Y_UP),
    # The URDF ball is 1 m across; a real size-5 football is 0.22 m.
    "soccerball": _Builtin(urdf="soccerball.urdf", real_diameter=0.22),
    "toys/cube": _Builtin(mesh="toys/cube.obj"),
    "toys/cylinder": _Builtin(mesh="toys/cylinder.obj"),
    "toys/prism": _Builtin(mesh="toys/prism.obj"),
    "toys/shape_sorter": _Builtin(mesh="toys/shape_sorter.obj", scale=0.5),
}


CATALOGUE = "catalogue/"  # built-in names of small furniture-library models: catalogue/<item id>


def catalogue_objects() -> list[str]:
    """The furniture library's small items (books, cups, plants, toys) as built-in object names."""
    from .library import furniture

    try:
        return [f"{CATALOGUE}{i.id}" for i in furniture.small_items()]
    except furniture.LibraryError:
        return []


def _catalogue_item(name: str):
    from .library import furniture

    item_id = name.removeprefix(CATALOGUE)
    try:
        return furniture.find(item_id)
    except (KeyError, furniture.LibraryError) as e:
        close = difflib.get_close_matches(item_id, [i.id for i in furniture.small_items()], n=3)
        hint = f" (did you mean {', '.join(CATALOGUE + c for c in close)}?)" if close else ""
        raise AssetError(f"built-in object {name!r}: not in the furniture library{hint}") from e


def builtin_objects() -> list[str]:
    names = list(_BUILTINS)
    try:
        ru = pybullet_data_root() / "random_urdfs"
        names += sorted(f"random_urdfs/{p.name}" for p in ru.iterdir() if (p / f"{p.name}.urdf").is_file())
    except (AssetError, OSError):
        pass
    return names


def _builtin_def(name: str) -> _Builtin:
    if name in _BUILTINS:
        return _BUILTINS[name]
    m = re.fullmatch(r"random_urdfs/(\d{3})", name)
    if m and (pybullet_data_root() / name / f"{m.group(1)}.urdf").is_file():
        return _Builtin(urdf=f"{name}/{m.group(1)}.urdf")
    close = difflib.get_close_matches(name, list(_BUILTINS), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise AssetError(
        f"built-in object {name!r}: unknown{hint}; known: {', '.join(_BUILTINS)}, random_urdfs/000..999"
    )


def _mtl_texture(obj_path: Path) -> tuple[Path | None, tuple[float, float, float] | None]:
    """(map_Kd texture, Kd colour) of an OBJ's first material library; the texture checked."""
    try:
        return _first_mtl_texture(obj_path)
    except MeshFileError as e:
        raise AssetError(str(e)) from None


def _first_mtl(obj_path: Path) -> Path | None:
    statements = obj_reader.mtllib_statements(obj_path)
    if not statements:
        return None
    lineno, name = statements[0]
    return referenced_file(obj_path, name, f"{obj_path}:{lineno}: mtllib")


def _first_mtl_texture(obj_path: Path):
    mtl = _first_mtl(obj_path)
    if mtl is None:
        return None, None
    mt = read_file(mtl).decode("utf-8", errors="replace")
    tex = re.search(r"^\s*map_Kd\s+(?:-\S+\s+\S+\s+)*(.+?)\s*$", mt, re.M)
    kd = re.search(r"^\s*Kd\s+(\S+)\s+(\S+)\s+(\S+)", mt, re.M)
    tex_path = None
    if tex:
        tex_path = obj_reader.texture_file(mtl, tex.group(1), mt.count("\n", 0, tex.start()) + 1, "map_Kd")
    colour = None
    if kd:
        try:
            colour = tuple(float(x) for x in kd.groups())
        except ValueError:
            raise MeshFileError(f"{mtl}:{mt.count(chr(10), 0, kd.start()) + 1}: Kd: expected 3 numbers") from None
    return tex_path, colour


# --------------------------------------------------------------------------- mesh readers


def parse_urdf(path: Path) -> list[urdf_reader.Visual]:
    try:
        return urdf_reader.parse_urdf(path)
    except MeshFileError as e:
        raise AssetError(str(e)) from None


def read_any_mesh(path: Path) -> tuple[MeshData, str | None]:
    """Read a PLY/OBJ/GLB/STL in its own units -> (mesh, texture named by a PLY header)."""
    require_file(path)
    if path.stat().st_size == 0:
        raise AssetError(f"{path}: empty file")
    if path.suffix.lower() not in (".ply", ".obj", ".glb", ".gltf", ".stl", ".off"):
        raise AssetError(f"{path}: unsupported mesh format {path.suffix!r} (PLY, OBJ, GLB, STL)")
    try:
        if path.suffix.lower() == ".ply":
            return ply.ply_to_mesh(path)
        return single.read_single(path), None
    except MeshFileError as e:
        raise AssetError(str(e)) from None


def _primitive_mesh(prim: tuple) -> MeshData:
    from .meshfiles import primitives as procedural

    kind, args = prim
    if kind == "box":
        return procedural.box(args)
    if kind == "cylinder":
        return procedural.cylinder(args[0], args[1])
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=3, radius=args[0])
    return MeshData(vertices=np.asarray(s.vertices, np.float32), faces=np.asarray(s.faces, np.int32),
                    normals=np.asarray(s.vertex_normals, np.float32))


def finish_mesh(mesh: MeshData, what: str) -> MeshData:
    """Validate, fill normals, cast to the normalised dtypes; errors name ``what``."""
    v = np.asarray(mesh.vertices, np.float64)
    if v.ndim != 2 or len(v) == 0 or len(mesh.faces) == 0:
        raise AssetError(f"{what}: empty mesh (no vertices or triangles)")
    f = np.asarray(mesh.faces)
    if f.min() < 0 or f.max() >= len(v):  # before normals are computed from them
        raise AssetError(f"{what}: face indices out of range (0..{len(v) - 1}, found {int(f.min())}..{int(f.max())})")
    if not np.isfinite(v).all():
        raise AssetError(f"{what}: mesh has NaN or infinite vertex coordinates")
    normals = mesh.normals
    if normals is None or not np.isfinite(normals).all():
        normals = _vertex_normals(v, mesh.faces)
    n = np.asarray(normals, np.float64)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    out = MeshData(
        vertices=v.astype(np.float32),
        faces=np.asarray(mesh.faces, np.int32),
        normals=n.astype(np.float32),
        uv=None if mesh.uv is None else np.asarray(mesh.uv, np.float32),
        colors=mesh.colors,
    )
    try:
        return out.validate(what)
    except MeshFormatError as e:
        raise AssetError(str(e)) from e


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    f = np.asarray(f)
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # area-weighted
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], fn)
    bad = np.linalg.norm(n, axis=1) < 1e-20
    n[bad] = (0.0, 0.0, 1.0)
    return n


def mesh_stats(v: np.ndarray) -> tuple[float, tuple, tuple]:
    """(diameter, bbox_min, extents) in the mesh's units; diameter over convex-hull vertices only."""
    v = np.asarray(v, np.float64)
    pts = v
    if len(v) > 64:
        try:
            from scipy.spatial import ConvexHull

            pts = v[ConvexHull(v).vertices]
        except Exception:  # degenerate (flat) point sets: fall back to all points
            pts = v
    if len(pts) > 6000:  # a hull this large is rare; bound memory of the pairwise pass
        pts = pts[np.linspace(0, len(pts) - 1, 6000).astype(int)]
    diam = 0.0
    for i in range(0, len(pts), 1024):
        d = np.linalg.norm(pts[i:i + 1024, None, :] - pts[None, :, :], axis=-1)
        diam = max(diam, float(d.max()))
    lo, hi = v.min(0), v.max(0)
    return diam, tuple(float(x) for x in lo), tuple(float(x) for x in hi - lo)


# --------------------------------------------------------------------------- sources


@dataclass(frozen=True)
class _Source:
    name: str
    kind: str  # 'bop' | 'mesh' | 'builtin'
    obj_id: int | None
    path: Path | None  # mesh file (bop/mesh) or URDF/OBJ (builtin)
    unit: str
    label: str  # for messages and ObjectAsset.source
    builtin: _Builtin | None = None
    field: str | None = None  # the spec field that names the file, where the spec names one

    def files(self) -> list[Path]:
        """Every file whose bytes determine the converted asset (fast: no mesh parsing)."""
        if self.kind == "catalogue":  # the library archive the model is unpacked from
            from .library import furniture

            return [furniture.library_dir() / f"{_catalogue_item(self.name).archive}.sh3f"]
        if self.kind == "builtin":
            b = self.builtin
            root = pybullet_data_root()
            if b.urdf:
                urdf = root / b.urdf
                if not urdf.is_file():
                    raise AssetError(f"built-in {self.name!r}: {urdf} missing from pybullet_data")
                out = [urdf]
                for vis in parse_urdf(urdf):
                    if vis.mesh is not None:
                        out += _mesh_and_material_files(vis.mesh, self.label)
                return out
            return _mesh_and_material_files(root / b.mesh, self.label)
        files = _own_mesh_files(self.path, self.label, self.field) if self.kind == "mesh" else [self.path]
        if self.path.suffix.lower() != ".ply":
            return files
        tex = _bop_texture_path(self.path)
        if tex is not None:
            check_texture(tex, self.label)
            files.append(tex)
        return files

    def fingerprint(self) -> str:
        params = {
            "v": CONVERSION_VERSION,
            "kind": self.kind,
            "unit": self.unit,
            "builtin": None if self.builtin is None else [self.builtin.scale, list(self.builtin.up_fix),
                                                         self.builtin.real_diameter, BUILTIN_ORIGIN],
            "files": [file_digest(p, self.label) for p in self.files()],
        }
        if self.kind == "catalogue":  # one archive holds many models
            params["item"] = self.name
        return _hash_json(params)


def _own_mesh_files(mesh: Path, what: str, field: str | None) -> list[Path]:
    """A spec's own mesh file and every file it names (an OBJ's material libraries and maps, a
    glTF's buffers and images), each checked as scene files' are: in the mesh's folder, a regular
    file (a FIFO would hang the reader), an image within the pixel limit."""
    require_file(mesh, what)
    try:
        check_mesh_file(mesh, what)
        suffix = mesh.suffix.lower()
        if suffix == ".obj":
            return obj_reader.source_files(mesh)
        if suffix in (".gltf", ".glb"):
            return gltf_reader.source_files(mesh)
        return [mesh]
    except MeshFileError as e:
        raise AssetError(str(e), field=field) from None


def _mesh_and_material_files(mesh: Path, what: str) -> list[Path]:
    require_file(mesh, f"{what}: mesh file")
    try:
        check_mesh_file(mesh, what)
        out = [mesh]
        if mesh.suffix.lower() == ".obj":
            mtl = _first_mtl(mesh)
            tex, _ = _first_mtl_texture(mesh)
            out += [p for p in (mtl, tex) if p is not None]
    except MeshFileError as e:
        raise AssetError(str(e)) from None
    return out


def _bop_texture_name(ply: Path) -> str | None:
    """Texture a PLY header names, read from the header only."""
    if ply.suffix.lower() != ".ply" or not_a_file(ply) is not None:
        return None
    try:
        with open(ply, "rb") as f:
            head = f.read(4096)
    except OSError:
        return None
    m = re.search(rb"^comment\s+TextureFile\s+(.+?)\s*$", head, re.M | re.I)
    return m.group(1).decode(errors="replace") if m else None


def _bop_texture_path(ply: Path) -> Path | None:
    """The texture a PLY header names, checked (in the PLY's folder); None when it is missing."""
    name = _bop_texture_name(ply)
    if name is None:
        return None
    try:
        return referenced_file(ply, name, f"{ply}: comment TextureFile")
    except MeshFileError as e:
        raise AssetError(str(e)) from None


def _bop_folder(objects: spec_mod.Objects, spec_dir: Path) -> tuple[Path, list[int], str | None]:
    """(folder, obj ids, a note for the user or None). A folder without ``models_info.json`` gets
    it computed as the BOP toolkit does, cached by the models' content (``bopmodels``)."""
    try:
        folder = expand_path(objects.path, spec_dir, repr(objects.path))
    except AssetError as e:
        raise AssetError(str(e), field="objects.path") from None
    if not folder.is_dir():
        what = "is not a folder" if os.path.lexists(folder) else "does not exist"
        raise AssetError(f"objects.path: BOP models folder {folder} {what}. {BOP_HELP}", field="objects.path")
    info = folder / "models_info.json"
    note = None
    if info.is_file():
        try:
            ids = sorted(int(k) for k in json.loads(info.read_text()))
        except (ValueError, TypeError, RecursionError) as e:
            raise AssetError(f"{info}: corrupt models_info.json ({type(e).__name__})", field="objects.path") from None
    else:
        ids = bopmodels.model_ids(folder)
        if not ids:
            raise AssetError(f"objects.path: {folder} has neither models_info.json nor obj_XXXXXX.ply files: "
                             f"not a BOP models folder. {BOP_HELP}", field="objects.path")
        _, cached = bopmodels.computed_models_info(folder, cache_dir(), _model_points)
        note = (f"objects.path: {folder} has no models_info.json; computed it for its {len(ids)} models as the "
                f"BOP toolkit's calc_model_info.py does (cached as {cached})")
    bad = bopmodels.bad_model_ids(ids)
    if bad:
        raise AssetError(f"objects.path: {folder} has a model of obj_id {bad[0]} (obj_{bad[0]:06d}); BOP's ids start at "
                         "1: renumber it", field="objects.path")
    if objects.ids is not None:
        unknown = sorted(set(objects.ids) - set(ids))
        if unknown:
            raise AssetError(f"objects.ids: {unknown} not in {folder} (has {ids})", field="objects.ids")
        ids = sorted(set(objects.ids))
    return folder, ids, note


def _model_points(path: Path) -> np.ndarray:
    mesh, _ = read_any_mesh(path)
    return mesh.vertices


def bop_folder_notes(objects: spec_mod.Objects, spec_dir: Path) -> list[str]:
    """What resolving the spec's BOP folder did that the user should hear about."""
    if objects.path is None:
        return []
    note = _bop_folder(objects, Path(spec_dir))[2]
    return [note] if note else []


def _sources(objects: spec_mod.Objects, spec_dir: Path) -> list[_Source]:
    spec_dir = Path(spec_dir)
    out: list[_Source] = []
    used: set[int] = set()
    if objects.path is not None:
        folder, ids, _ = _bop_folder(objects, spec_dir)
        for i in ids:
            p = folder / f"obj_{i:06d}.ply"
            if not_a_file(p) == "not found":
                raise AssetError(f"obj_{i:06d}: model file {p} is missing (listed in models_info.json)",
                                 field="objects.path")
            require_file(p, f"obj_{i:06d}")
            out.append(_Source(f"obj_{i:06d}", "bop", i, p, "mm", str(p)))
            used.add(i)
    builtins = [b if isinstance(b, spec_mod.BuiltinObject) else spec_mod.BuiltinObject(name=b)
                for b in objects.builtin]
    pending: list[tuple[str, object, str]] = ([("builtin", b, "objects.builtin") for b in builtins]
                                              + [("mesh", m, f"objects.meshes.{j}.path") for j, m in enumerate(objects.meshes)])
    # Explicit ids first so that automatic ones never collide with an id given later in the list.
    for _, item, _ in pending:
        if item.obj_id is not None:
            if item.obj_id in used:
                raise AssetError(f"obj_id {item.obj_id} is used twice (by {getattr(item, 'name', None) or item.path})")
            used.add(item.obj_id)
    names = {s.name for s in out}
    # A BOP folder's ids are its dataset's (LM-O's 1, 5, 6, ... leave LM's 2, 3, 4 out): ids given
    # automatically start after its largest, and are the lowest free ones in the order listed:
    # [a, b, c (obj_id: 7)] -> 1, 2, 7.
    first_free = max((s.obj_id for s in out), default=0) + 1
    for kind, item, field in pending:
        oid = item.obj_id
        if oid is None:
            oid = next(i for i in itertools.count(first_free) if i not in used)
            used.add(oid)
        if kind == "builtin" and item.name.startswith(CATALOGUE):
            src = _Source(item.name, "catalogue", oid, None, "m", f"furniture:{_catalogue_item(item.name).id}")
        elif kind == "builtin":
            b = _builtin_def(item.name)
            path = pybullet_data_root() / (b.urdf or b.mesh)
            src = _Source(item.name, "builtin", oid, path, "m", f"pybullet_data:{item.name}", b)
        else:
            p = expand_path(item.path, spec_dir, f"mesh {item.path!r}")
            try:
                require_file(p, f"mesh {item.path!r}")
            except AssetError as e:
                raise AssetError(str(e), field=field) from None
            src = _Source(item.name or f"obj_{oid:06d}", "mesh", oid, p, item.unit, str(p), field=field)
        if src.name in names:
            raise AssetError(f"object name {src.name!r} appears twice in 'objects'")
        names.add(src.name)
        out.append(src)
    return sorted(out, key=lambda s: s.obj_id)


def bop_folder_ids(objects: spec_mod.Objects, spec_dir: Path) -> list[int]:
    """The obj ids of ``objects.path``, a BOP models folder, checked as a build reads it."""
    return _bop_folder(objects, Path(spec_dir))[1]


def object_fingerprints(objects: spec_mod.Objects, spec_dir: Path) -> dict[str, str]:
    """name -> content hash of each object's source files (+ unit, conversion version). Fast."""
    return {s.name: s.fingerprint() for s in _sources(objects, spec_dir)}


def object_size_problems(objects: spec_mod.Objects, spec_dir: Path, fingerprints: dict[str, str]) -> list[AssetError]:
    """Each of the user's objects whose size says its unit is wrong, before any work (the build's
    conversion checks it exactly, after physics has started): a BOP model by its models_info.json
    diameter (millimetres), a mesh file by its bounding box in its declared unit, whose diagonal
    bounds its diameter from above and, over the square root of 3, from below. ``fingerprints``:
    ``object_fingerprints``' of the same objects (a mesh's size is cached by it)."""
    problems = []
    sources = [s for s in _sources(objects, spec_dir) if s.kind in ("bop", "mesh")]
    info = _bop_diameters(objects, Path(spec_dir)) if any(s.kind == "bop" for s in sources) else {}
    for src in sources:
        if src.kind == "bop":
            mm = info.get(src.obj_id)
            if mm is not None and not MIN_DIAMETER <= mm / 1000.0 <= MAX_DIAMETER:
                problems.append(AssetError(
                    f"{src.name}: diameter {mm:.4g} in models_info.json, which BOP reads as millimetres: "
                    f"objects are {MIN_DIAMETER * 1000:g} mm to {MAX_DIAMETER:g} m across; scale the models to "
                    "millimetres (BOP's unit)", field="objects.path"))
            continue
        try:
            lo, hi = _diameter_bounds(src, fingerprints[src.name])
        except AssetError as e:  # a mesh that cannot be read: named here, not in a worker
            problems.append(AssetError(str(e), field=src.field))
            continue
        if hi < MIN_DIAMETER or lo > MAX_DIAMETER:
            problems.append(AssetError(
                f"{src.path.name}: {'at most' if hi < MIN_DIAMETER else 'at least'} "
                f"{hi if hi < MIN_DIAMETER else lo:.4g} m across with unit {src.unit!r}; objects are "
                f"{MIN_DIAMETER * 1000:g} mm to {MAX_DIAMETER:g} m across: is the file in another unit?",
                field=src.field.removesuffix(".path") + ".unit"))
    return problems


def _bop_diameters(objects: spec_mod.Objects, spec_dir: Path) -> dict[int, float]:
    """obj_id -> diameter (the folder's units, millimetres for BOP) from its models_info.json, as
    given or as computed (and cached) when it has none."""
    folder = expand_path(objects.path, spec_dir, "objects.path")
    given = folder / "models_info.json"
    try:
        info = json.loads(given.read_text()) if given.is_file() else \
            bopmodels.computed_models_info(folder, cache_dir(), _model_points)[0]
        return {int(k): float(v["diameter"]) for k, v in info.items()
                if isinstance(v, dict) and isinstance(v.get("diameter"), (int, float))}
    except (OSError, ValueError, TypeError, RecursionError):
        return {}  # _bop_folder names a corrupt file


def _diameter_bounds(src: _Source, fingerprint: str) -> tuple[float, float]:
    """(least, greatest) diameter in metres a mesh file's vertices allow, from their bounding box;
    cached by the file's content, as validate and every build ask again."""
    cached = cache_dir() / "sizes" / f"{fingerprint}.json"
    try:
        lo, hi = json.loads(cached.read_text())
        return float(lo), float(hi)
    except (OSError, ValueError, TypeError):
        pass
    bounds = _measured_bounds(src)
    atomic_write_bytes(cached, json.dumps(bounds).encode())
    return bounds


def _measured_bounds(src: _Source) -> tuple[float, float]:
    mesh, _ = read_any_mesh(src.path)
    v = np.asarray(mesh.vertices, np.float64)
    if not len(v) or not np.isfinite(v).all():
        return 0.0, 0.0  # the conversion names such a mesh; no size to judge here
    diagonal = float(np.linalg.norm(v.max(axis=0) - v.min(axis=0))) * UNIT_SCALE[src.unit]
    return diagonal / np.sqrt(3.0), diagonal


# --------------------------------------------------------------------------- conversion


def _convert(src: _Source, cache: Path) -> tuple[MeshData, str | None, tuple[float, float, float] | None]:
    """Source -> (mesh in metres, texture path or None, linear base colour or None)."""
    if src.kind == "builtin":
        return _convert_builtin(src)
    if src.kind == "catalogue":
        return _convert_catalogue(src, cache), None, None
    mesh, tex_name = read_any_mesh(src.path)
    mesh = finish_mesh(mesh, src.label)
    texture = None
    if tex_name:
        tex = _bop_texture_path(src.path)
        if tex is not None:
            check_texture(tex, src.label)
            texture = str(tex)
        else:
            msg = f"{src.label}: texture {tex_name} named in the PLY header is missing; using a plain material"
            warnings.warn(msg, stacklevel=3)
    colour = None
    if src.path.suffix.lower() == ".obj":  # its MTL's map_Kd (with UVs) or Kd, as for built-ins
        tex, kd = _mtl_texture(src.path)
        if tex is not None and mesh.uv is not None:
            check_texture(tex, src.label)
            texture = str(tex)
        elif kd is not None:
            colour = kd
    s = UNIT_SCALE[src.unit]
    mesh = replace(mesh, vertices=(mesh.vertices.astype(np.float64) * s).astype(np.float32))
    return mesh, texture, colour


def _convert_builtin(src: _Source):
    from .meshfiles import primitives as procedural

    b = src.builtin
    root = pybullet_data_root()
    up = np.eye(4)
    up[:3, :3] = rpy_matrix(*b.up_fix)
    if b.urdf:
        visuals = parse_urdf(root / b.urdf)
    else:
        visuals = [urdf_reader.Visual(root / b.mesh, None, (b.scale,) * 3, np.eye(4), None)]
    parts, texture, colour = [], None, None
    for vis in visuals:
        if vis.mesh is not None:
            m, _ = read_any_mesh(vis.mesh)
            m = finish_mesh(m, src.label)
            if vis.mesh.suffix.lower() == ".obj":
                tex, kd = _mtl_texture(vis.mesh)
                if tex is not None and texture is None and m.uv is not None:
                    check_texture(tex, src.label)
                    texture = str(tex)
                if colour is None and kd is not None and vis.rgba is None:
                    colour = kd  # MTL Kd is already linear-ish reflectance
        else:
            m = _primitive_mesh(vis.primitive)
        if vis.rgba is not None and colour is None:
            colour = tuple(float(x) for x in srgb_to_linear(np.asarray(vis.rgba[:3])))
        S = np.diag([*vis.scale, 1.0])
        parts.append(procedural.transform_mesh(m, up @ vis.matrix @ S))
    if len({p.uv is None for p in parts}) > 1:  # UVs only matter with one textured part
        parts = [replace(p, uv=None) for p in parts]
        texture = None
    mesh = procedural.concatenate(parts)
    v = mesh.vertices.astype(np.float64)
    v = v - (v.min(0) + v.max(0)) / 2  # BOP's model origin: the centre of the 3D bounding box
    if b.real_diameter:
        diam, _, _ = mesh_stats(v)
        v = v * (b.real_diameter / diam)
    mesh = replace(mesh, vertices=v.astype(np.float32))
    return finish_mesh(mesh, src.label), texture, colour


def _convert_catalogue(src: _Source, cache: Path) -> MeshData:
    """A small library model as one object: sized to the catalogue, +Z up, its origin at the centre
    of its bounding box (as BOP's models); each part's colour (its base colour times its texture's
    mean, when it has one) baked into vertex colours, so every backend and BOP's model carry it."""
    from . import furnish
    from .library import furniture
    from .meshfiles import primitives, read_parts

    item = _catalogue_item(src.name)
    parts = furnish.normalise_parts(read_parts(furniture.extract(item, cache), cache / "assets" / "textures"), item)
    meshes = []
    for part in parts:
        colour = np.asarray(part.material.base_color, np.float64)
        if part.material.texture:
            colour = colour * mean_linear_colour(Path(part.material.texture))
        srgb = np.clip(np.rint(linear_to_srgb(colour) * 255), 0, 255).astype(np.uint8)
        rgba = np.tile(np.append(srgb, 255).astype(np.uint8), (len(part.mesh.vertices), 1))
        meshes.append(replace(part.mesh, uv=None, colors=rgba))
    mesh = primitives.concatenate(meshes)
    v = mesh.vertices.astype(np.float64)
    mesh = replace(mesh, vertices=(v - (v.min(0) + v.max(0)) / 2).astype(np.float32))
    return finish_mesh(mesh, src.label)


@functools.lru_cache(maxsize=64)
def mean_linear_colour(path: Path) -> np.ndarray:
    """The mean linear colour of an sRGB texture file (as the renderers decode it)."""
    from PIL import Image

    with Image.open(path) as im:
        rgb = np.asarray(im.convert("RGB").resize((32, 32)), np.float64) / 255.0
    return srgb_to_linear(rgb).reshape(-1, 3).mean(0)


def check_photo(path: Path, what: str) -> None:
    """A photograph a backend draws behind the objects: its header opens as an image, within the
    pixel count PIL decodes without calling it a decompression bomb (what the photo backend reads
    with). Header only: a folder may hold thousands, and a broken body is named by the render."""
    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                im.size  # noqa: B018 (the header is read)
    except Image.DecompressionBombError:
        raise AssetError(f"{what}: {path} claims over {2 * Image.MAX_IMAGE_PIXELS:,} pixels; scale it down or "
                         "remove it from the folder") from None
    except (OSError, SyntaxError, ValueError, EOFError) as e:  # PIL's ways of saying "not an image"
        raise AssetError(f"{what}: {path} is not an image PIL can read ({type(e).__name__})") from None


def check_texture(path: Path, what: str) -> None:
    """A texture must be an image that decodes within the pixel limit: a corrupt one would render
    as garbage or crash a worker, a huge one fill its memory (``bake.check_image``)."""
    try:
        bake.check_image(path, what)
    except MeshFileError as e:
        raise AssetError(str(e)) from None


def store_mesh(mesh: MeshData, key: str, cache: Path, comments: tuple[str, ...] = ()) -> tuple[Path, str]:
    """Write the normalised PLY as ``<cache>/assets/<key>.ply`` (once) -> (path, mesh_key)."""
    path = Path(cache) / "assets" / f"{key}.ply"
    data = mesh_bytes(drop_overlapping(mesh.with_usable_normals().with_usable_uv()), comments)
    if not (path.is_file() and path.stat().st_size == len(data)):
        atomic_write_bytes(path, data)
    return path, hashlib.sha256(data).hexdigest()


def store_texture(src: Path, cache: Path) -> Path:
    """A self-contained copy of a texture, ``<cache>/assets/textures/<sha256><suffix>``: a cached
    asset never points into a user's folder, whose file may change or vanish after it was cached
    (two folders with the same mesh bytes share one cache entry)."""
    data = src.read_bytes()
    path = Path(cache) / "assets" / "textures" / f"{hashlib.sha256(data).hexdigest()}{src.suffix.lower()}"
    if not (path.is_file() and path.stat().st_size == len(data)):
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(path, data)
    return path


def _load_or_convert(src: _Source, cache: Path) -> dict:
    key = src.fingerprint()
    meta_path = Path(cache) / "assets" / f"{key}.json"
    ply_path = meta_path.with_suffix(".ply")
    if meta_path.is_file() and ply_path.is_file():
        try:
            meta = json.loads(meta_path.read_text())
            # A texture copy deleted from the cache is remade with the rest.
            if meta.get("v") == CONVERSION_VERSION and (not meta.get("texture") or Path(meta["texture"]).is_file()):
                if meta.get("texture_missing"):
                    msg = f"{src.label}: texture {meta['texture_missing']} named in the PLY header is missing; using a plain material"
                    warnings.warn(msg, stacklevel=3)
                return meta
        except (ValueError, OSError):
            pass  # a torn or stale sidecar is simply rebuilt
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mesh, texture, colour = _convert(src, cache)
    for w in caught:  # re-emit so callers see them, and remember for cache hits
        warnings.warn(w.message, stacklevel=3)
    diam, lo, ext = mesh_stats(mesh.vertices)
    if not (MIN_DIAMETER <= diam <= MAX_DIAMETER):
        raise AssetError(
            f"{src.label}: object diameter {diam:.4g} m is outside [{MIN_DIAMETER}, {MAX_DIAMETER}] m "
            f"with unit {src.unit!r}; check 'unit'"
        )
    # No comments naming the source: mesh_key then depends on geometry alone.
    path, mesh_key = store_mesh(mesh, key, cache)
    if texture is not None:
        texture = str(store_texture(Path(texture), cache))
    tex_missing = None
    if texture is None and src.kind in ("bop", "mesh"):
        named = _bop_texture_name(src.path)
        tex_missing = Path(named).name if named is not None and _bop_texture_path(src.path) is None else None
    meta = {
        "v": CONVERSION_VERSION, "mesh_key": mesh_key, "diameter": diam, "bbox_min": lo, "extents": ext,
        "texture": texture, "color": colour, "has_colors": mesh.colors is not None,
        "texture_missing": tex_missing,
    }
    atomic_write_bytes(meta_path, json.dumps(meta, sort_keys=True).encode())
    return meta


def _material(src: _Source, meta: dict, overrides: dict[str, spec_mod.Material], spec_dir: Path) -> MaterialIR:
    if meta["texture"]:
        base = MaterialIR(base_color=(1.0, 1.0, 1.0), texture=meta["texture"], use_vertex_colors=False)
    elif meta["color"] is not None:
        base = MaterialIR(base_color=tuple(meta["color"]), use_vertex_colors=meta["has_colors"])
    else:
        base = MaterialIR(use_vertex_colors=meta["has_colors"])
    over = None
    for key in (src.name, str(src.obj_id), "default"):  # most specific wins
        if key in overrides:
            over = overrides[key]
            break
    if over is None:
        return base
    texture = base.texture
    if over.texture is not None:
        tex = expand_path(over.texture, spec_dir, f"objects.materials texture for {src.name}")
        if not tex.is_file():
            raise AssetError(f"{src.name}: material texture not found: {tex}")
        check_texture(tex, src.name)
        texture = str(tex)
    gain = np.asarray(over.color_gain, np.float64)
    if over.color is not None:
        return MaterialIR(base_color=tuple(float(c) for c in np.asarray(over.color) * gain), use_vertex_colors=False,
                          texture=None, roughness=over.roughness, metallic=over.metallic, specular=over.specular)
    return MaterialIR(
        base_color=tuple(float(c) for c in (np.ones(3) if texture else np.asarray(base.base_color)) * gain),
        use_vertex_colors=over.use_vertex_colors and base.use_vertex_colors and texture is None,
        texture=texture, roughness=over.roughness, metallic=over.metallic, specular=over.specular,
    )


def resolve_objects(objects: spec_mod.Objects, spec_dir: Path, cache: Path | None = None) -> list[ObjectAsset]:
    """Resolve and convert (once, cached) every object of the spec; sorted by obj_id."""
    cache = Path(cache) if cache is not None else cache_dir()
    out = []
    for src in _sources(objects, Path(spec_dir)):
        meta = _load_or_convert(src, cache)
        out.append(ObjectAsset(
            obj_id=src.obj_id,
            name=src.name,
            mesh_path=str(cache / "assets" / f"{src.fingerprint()}.ply"),
            mesh_key=meta["mesh_key"],
            material=_material(src, meta, objects.materials, Path(spec_dir)),
            diameter=float(meta["diameter"]),
            bbox_min=tuple(meta["bbox_min"]),
            extents=tuple(meta["extents"]),
            source=src.label,
        ))
    return out

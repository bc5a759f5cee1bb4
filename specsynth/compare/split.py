"""Reading a BOP split: its scenes, images, cameras and ground truth, checked before any work.

A split is a folder of scene folders (``000002/``) each holding ``rgb/`` (png, jpg or tif; BOP's
``gray/`` too), ``scene_gt.json`` and, optionally, ``scene_camera.json``, ``scene_gt_info.json``,
``mask_visib/`` and ``depth/``; the intrinsics come from ``scene_camera.json`` or the dataset's
``camera.json`` (in the split's parent folder). :func:`open_split` accepts the split folder, one
scene folder, a dataset folder with one split, a specsynth build folder (its ``bop/<split>``), or
``dataset:NAME/SPLIT`` for an installed real set.

Every problem is a :class:`SplitError` naming the file and, inside JSON, the entry (``"17"[2]
.cam_t_m2c``), raised by :func:`open_split` before a single image is decoded; file contents are
never quoted. Files must be regular files inside the split's dataset folder (links resolved, folders
included), and numbers within physical bounds.
"""

from __future__ import annotations

import json
import math
import os
import re
import stat
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..files import RepeatedKey, is_image_id, loads_json_strict

SCENE_DIR = re.compile(r"^[0-9]{6}$")
LOOKS_LIKE_SCENE = re.compile(r"^\d{6}$")  # any Unicode digits: "٠٠٠٠٠٢" would be scene 2 to int()
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff")
MAX_JSON_BYTES = 1 << 30  # a scene_gt.json of a million images is ~300 MB
MAX_IMAGES = 10_000_000
MAX_INSTANCES = 1000  # in one image; BOP's most crowded (ITODD, HB) have under 100
FOCAL_RANGE = (1e-3, 1e6)  # pixels: wider than any lens on any sensor, short of overflowing a projection
MAX_CENTRE = 1e6  # pixels: |cx|, |cy| (and skew)
MAX_BOX = 1e7  # pixels: |any bbox coordinate|
MAX_DISTANCE_MM = 1e7  # |cam_t_m2c|: 10 km
DEPTH_SCALE_RANGE = (0.0, 1e3)  # mm per depth unit, the lower bound excluded
DEPTH_MODES = ("I;16", "I;16B", "I;16L", "I")  # a 16-bit grey PNG ("I" in older Pillow)
MASK_MODES = ("1", "L")


class SplitError(ValueError):
    """A split that cannot be read as BOP: names the file and where in it."""


@dataclass(frozen=True)
class Instance:
    obj_id: int
    gt_index: int
    R_m2c: np.ndarray  # 3x3
    t_m2c: np.ndarray  # metres
    bbox_obj: tuple[float, float, float, float] | None = None  # from scene_gt_info (given or computed)
    bbox_visib: tuple[float, float, float, float] | None = None
    px_count_all: int | None = None
    px_count_visib: int | None = None
    visib_fract: float | None = None


@dataclass(frozen=True)
class SplitImage:
    scene_id: int
    im_id: int
    rgb: Path
    K: np.ndarray
    width: int
    height: int
    instances: tuple[Instance, ...]
    R_w2c: np.ndarray | None = None  # the scene's world (Z up), when scene_camera.json gives it
    mask_visib: tuple[Path, ...] = ()  # per instance, when the split has them
    depth: Path | None = None  # uint16 PNG, value * depth_scale = mm
    depth_scale: float = 1.0

    @property
    def key(self) -> str:
        return f"{self.scene_id:06d}/{self.im_id:06d}"


@dataclass
class Split:
    """A checked split: its scene folders and what they hold. Images are read scene by scene when
    iterated (:meth:`iter_images`), so that a split of any size costs the same memory."""

    path: Path  # the split folder
    dataset: Path  # the folder holding camera.json and models/
    name: str
    scenes: list[Path] = field(default_factory=list)
    root: Path = Path("/")  # the dataset folder, links resolved: every file read lies inside it
    camera: tuple | None = None  # (K, width, height) of camera.json
    camera_scale: float = 1.0
    n_images: int = 0
    object_ids: frozenset[int] = frozenset()
    has_gt_info: bool = True
    has_masks: bool = True
    has_depth: bool = False
    synthetic: bool = False  # a specsynth build
    computed: Path | None = None  # masks and scene_gt_info.json computed for a split without them (gtinfo)

    def iter_images(self):
        """Every image, in scene and image-id order, read and checked as :func:`open_split` did."""
        for scene in self.scenes:
            yield from _read_scene(self, scene)

    @property
    def images(self) -> list[SplitImage]:
        """Every image at once: for small splits (a large one is streamed by :meth:`iter_images`)."""
        return list(self.iter_images())

    @property
    def models(self) -> Path | None:
        for name in ("models", "models_eval"):
            p = self.dataset / name
            if p.is_dir():
                return p
        return None

    def obj_ids(self) -> list[int]:
        return sorted(self.object_ids)


def _regular(path: Path, root: Path, what: str) -> Path:
    """``path`` if it is a regular file inside ``root`` (links resolved), else a SplitError."""
    try:
        st = os.stat(path)
    except OSError:
        raise SplitError(f"{path}: {what} not found") from None
    if not stat.S_ISREG(st.st_mode):
        raise SplitError(f"{path}: {what} is not a regular file")
    _inside(path, root, what)
    return path


def _inside(path: Path, root: Path, what: str) -> None:
    """A SplitError unless ``path``, links resolved (its folders' too), lies inside ``root``."""
    real = Path(os.path.realpath(path))
    if real != root and root not in real.parents:
        raise SplitError(f"{path}: {what} is a link out of the dataset folder {root}")


def _read_json(path: Path, root: Path, what: str):
    _regular(path, root, what)
    if path.stat().st_size > MAX_JSON_BYTES:
        raise SplitError(f"{path}: {what} is larger than {MAX_JSON_BYTES >> 20} MiB")
    try:
        return loads_json_strict(path.read_bytes())
    except RepeatedKey:
        raise SplitError(f"{path}: an object names one key twice (which entry is meant?)") from None
    except (ValueError, UnicodeDecodeError) as e:
        where = f" (line {e.lineno})" if hasattr(e, "lineno") else ""
        raise SplitError(f"{path}: not valid JSON{where}") from None
    except RecursionError:
        raise SplitError(f"{path}: JSON nested too deep to read") from None


def _number(v, path: Path, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise SplitError(f"{path}: {where}: expected a number, got {type(v).__name__}")
    if not math.isfinite(v):
        raise SplitError(f"{path}: {where}: not a finite number")
    return float(v)


_NUMBER_TYPES = frozenset((int, float))  # by exact type: a bool is not a number here


def _numbers(v, n: int, path: Path, where: str) -> np.ndarray:
    if not isinstance(v, list) or len(v) != n:
        raise SplitError(f"{path}: {where}: expected a list of {n} numbers")
    if all(type(x) in _NUMBER_TYPES for x in v):
        a = np.array(v, np.float64)
        if np.isfinite(a).all():
            return a
    return np.array([_number(x, path, f"{where}[{k}]") for k, x in enumerate(v)], np.float64)  # names the bad one


def _within(v: float, lo: float, hi: float, path: Path, where: str, unit: str) -> float:
    if not lo <= v <= hi:
        raise SplitError(f"{path}: {where}: expected {lo:g} to {hi:g} {unit}")
    return v


def _depth_scale(v, path: Path, where: str) -> float:
    scale = _number(v, path, where)
    if not DEPTH_SCALE_RANGE[0] < scale <= DEPTH_SCALE_RANGE[1]:
        raise SplitError(f"{path}: {where}: expected a depth scale above 0 and at most {DEPTH_SCALE_RANGE[1]:g} "
                         "(mm per depth unit)")
    return scale


def _int(v, path: Path, where: str, lo: int = 0) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < lo:
        raise SplitError(f"{path}: {where}: expected an integer >= {lo}")
    return v


def _image_key(k: str, path: Path) -> int:
    if not is_image_id(k):
        raise SplitError(f"{path}: a key that is not a canonical image id (ASCII digits, no leading zeros)")
    return int(k)


def _not_rotations(R: np.ndarray) -> np.ndarray:
    """Which of the (N, 3, 3) matrices are not rotations. Published ground truth is orthonormal to
    ~1e-2 (LM-O has det 1.014); garbage is far off."""
    off = np.abs(R @ R.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2))
    return (np.abs(np.linalg.det(R) - 1.0) > 0.05) | (off > 0.05)


def _rotation(v, path: Path, where: str) -> np.ndarray:
    R = _numbers(v, 9, path, where).reshape(3, 3)
    if _not_rotations(R[None])[0]:
        raise SplitError(f"{path}: {where}: not a rotation matrix")
    return R


def _intrinsics(cam: dict, path: Path, where: str) -> tuple[np.ndarray, int | None, int | None]:
    if not isinstance(cam, dict):
        raise SplitError(f"{path}: {where}: expected an object")
    if "cam_K" in cam:
        K = _numbers(cam["cam_K"], 9, path, f"{where}.cam_K").reshape(3, 3)
        if not np.array_equal(K[2], [0.0, 0.0, 1.0]):
            raise SplitError(f"{path}: {where}.cam_K: the last row must be 0, 0, 1 (an intrinsic matrix)")
        names = [f"cam_K[{i}]" for i in (0, 4, 2, 5, 1, 3)]
    else:
        for k in ("fx", "fy", "cx", "cy"):
            if k not in cam:
                raise SplitError(f"{path}: {where}: needs cam_K or fx, fy, cx, cy")
        fx, fy, cx, cy = (_number(cam[k], path, f"{where}.{k}") for k in ("fx", "fy", "cx", "cy"))
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        names = ["fx", "fy", "cx", "cy", "skew", "skew"]
    for name, v in zip(names, (K[0, 0], K[1, 1])):
        _within(v, *FOCAL_RANGE, path, f"{where}.{name}", "pixels (a focal length)")
    for name, v in zip(names[2:], (K[0, 2], K[1, 2], K[0, 1], K[1, 0])):
        _within(v, -MAX_CENTRE, MAX_CENTRE, path, f"{where}.{name}", "pixels")
    for have, need in (("width", "height"), ("height", "width")):
        if have in cam and need not in cam:
            raise SplitError(f"{path}: {where}: missing {need} (it gives {have})")
    w = _int(cam["width"], path, f"{where}.width", 1) if "width" in cam else None
    h = _int(cam["height"], path, f"{where}.height", 1) if "height" in cam else None
    return K, w, h


@contextmanager
def open_image(path: Path, what: str = "image"):
    """``path`` opened by PIL (its header read; decoding happens in the ``with`` body), any failure a
    SplitError naming the file. A small file can claim gigapixels: past PIL's decompression-bomb
    limit (its warning's, not twice that) it is refused before anything is decoded."""
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                yield im
    except SplitError:
        raise
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise SplitError(f"{path}: the {what} claims more than {Image.MAX_IMAGE_PIXELS:,} pixels "
                         "(a decompression bomb?)") from None
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError, EOFError):
        raise SplitError(f"{path}: not a readable {what}") from None


def check_orientation(im, path: Path) -> None:
    """BOP images are stored as the camera's pixel grid, which K describes: an image tagged to be
    shown rotated or mirrored is refused (measured as shown, it would not match its ground truth)."""
    if im.format == "PNG" and "exif" not in im.info:
        return  # PIL would decode the image to look for an eXIf chunk after its pixels; read time does
    try:
        orientation = im.getexif().get(0x0112, 1)
    except Exception:  # noqa: BLE001 - PIL's EXIF parser raises many kinds on malformed data
        raise SplitError(f"{path}: the image's EXIF data cannot be read") from None
    if orientation != 1:
        raise SplitError(f"{path}: the image has an EXIF orientation other than 1 (rotated or mirrored); BOP "
                         "images are stored as the camera's pixel grid")


def _image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the file's header, without decoding it."""
    with open_image(path) as im:
        check_orientation(im, path)
        return im.size


def _check_depth(path: Path, size: tuple[int, int]) -> None:
    """A depth image's header: one 16-bit channel, the image's size."""
    with open_image(path, "depth image") as d:
        if d.mode not in DEPTH_MODES:
            raise SplitError(f"{path}: a depth image must be one channel of 16 bits (a 16-bit grey PNG)")
        if d.size != size:
            raise SplitError(f"{path}: the depth image is {d.size[0]} x {d.size[1]} pixels, its image "
                             f"{size[0]} x {size[1]}")


def _find_split(path: Path) -> tuple[Path, bool]:
    """The split folder a user's path names, and whether it is a specsynth build's."""
    if (path / "bop").is_dir() and (path / ".specsynth").is_dir():  # a build folder
        splits = sorted(p for p in (path / "bop").iterdir() if p.is_dir() and p.name != "models"
                        and not p.name.endswith("_right"))
        if len(splits) != 1:
            raise SplitError(f"{path}: a build with {len(splits)} splits in bop/; name one (e.g. {path}/bop/<split>)")
        return splits[0], True
    if (path / "scene_gt.json").exists() or (path / "rgb").is_dir():  # one scene folder
        return path, False
    if any(LOOKS_LIKE_SCENE.match(p.name) and p.is_dir() for p in path.iterdir()):
        return path, (path.parent.parent / ".specsynth").is_dir()
    splits = sorted(p for p in path.iterdir() if p.is_dir() and any(SCENE_DIR.match(q.name) for q in p.iterdir()))
    if len(splits) == 1:
        return splits[0], False
    if not splits:
        raise SplitError(f"{path}: holds no BOP split (no scene folders such as 000001/ with scene_gt.json)")
    raise SplitError(f"{path}: holds {len(splits)} splits ({', '.join(p.name for p in splits)}); name one")


def open_split(ref: str | Path, cache: Path | None = None) -> Split:
    """Read and check a split (see the module's doc) -> :class:`Split` with every image listed."""
    text = str(ref)
    if text.startswith("dataset:"):
        from ..assets.library import realsets
        from ..assets.library.cache import cache_dir

        try:
            path = realsets.resolve_ref(text, cache or cache_dir())
        except realsets.RealSetError as e:
            raise SplitError(f"{text}: {e}") from None
    else:
        path = Path(text)
    if not path.is_dir():
        raise SplitError(f"{path}: not a folder" if path.exists() else f"{path}: not found")
    split_dir, synthetic = _find_split(path)
    scenes = [split_dir] if ((split_dir / "scene_gt.json").exists() or (split_dir / "rgb").is_dir()) else \
        _scene_dirs(split_dir)
    if not scenes:
        raise SplitError(f"{split_dir}: holds no scene folders (000001/, ...)")
    single_scene = scenes == [split_dir]
    dataset = split_dir.parent.parent if single_scene else split_dir.parent
    root = Path(os.path.realpath(dataset))
    camera, camera_scale = None, 1.0
    if (dataset / "camera.json").exists():
        cam = _read_json(dataset / "camera.json", root, "camera.json")
        camera = _intrinsics(cam, dataset / "camera.json", "camera")
        camera_scale = _depth_scale(cam.get("depth_scale", 1.0), dataset / "camera.json", "depth_scale")
    split = Split(path=split_dir, dataset=dataset, name=split_dir.name if not single_scene else split_dir.parent.name,
                  scenes=scenes, root=root, camera=camera, camera_scale=camera_scale, synthetic=synthetic)
    split.has_gt_info = all((sc / "scene_gt_info.json").exists() for sc in scenes)
    split.has_masks = all((sc / "mask_visib").is_dir() for sc in scenes)
    split.has_depth = any((sc / "depth").is_dir() for sc in scenes)
    n, ids = 0, set()
    for im in split.iter_images():  # every check, before any work; nothing is kept but counts
        n += 1
        ids.update(i.obj_id for i in im.instances)
    if not n:
        raise SplitError(f"{split_dir}: holds no annotated images")
    if not ids:
        raise SplitError(f"{split_dir}: no annotated instances: every image's entry in scene_gt.json is empty")
    split.n_images, split.object_ids = n, frozenset(ids)
    return split


def _scene_dirs(split_dir: Path) -> list[Path]:
    """The scene folders of a split, in scene order. A folder named with other digits than ASCII
    ones is refused, not skipped: it would name a scene twice (int() reads any digits)."""
    out = []
    for p in split_dir.iterdir():
        if LOOKS_LIKE_SCENE.match(p.name) and p.is_dir():
            if not SCENE_DIR.match(p.name):
                raise SplitError(f"{split_dir}: a folder's name has non-ASCII digits (scene folders are named "
                                 "000001, ...)")
            out.append(p)
    return sorted(out)


def _root_of(split: Split, path: Path) -> Path:
    """The folder ``path`` must stay inside: the dataset's, or the computed folder's for its files."""
    if split.computed is not None and path.is_relative_to(split.computed):
        return Path(os.path.realpath(split.computed))
    return split.root


def _listing(folder: Path, root: Path, what: str) -> dict[str, Path]:
    """Name -> path of the regular files in ``folder`` (one directory read; only links are resolved,
    and a link out of ``root`` or to something that is not a regular file is an error)."""
    out = {}
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return out
    _inside(folder, root, f"the {what} folder")  # a folder linked out holds files that are not the dataset's
    for e in entries:
        if e.is_symlink():
            out[e.name] = _regular(Path(e.path), root, what)
        elif e.is_file(follow_symlinks=False):
            out[e.name] = Path(e.path)
    return out


def _scene_json(split: Split, scene: Path, name: str, required: bool = False) -> dict | None:
    """A scene's JSON file, from the computed folder (``scene_gt_info.json``, when computed) or the
    scene folder."""
    path = scene / name
    if split.computed is not None and name == "scene_gt_info.json":
        path = _computed_dir(split, scene) / name
        if not path.is_file():
            raise SplitError(f"{path}: computed {name} not found (remove the folder to compute it again)")
    if not path.exists():
        if required:
            raise SplitError(f"{path}: {name} not found (a BOP scene needs its ground-truth poses)")
        return None
    data = _read_json(path, _root_of(split, path), name)
    if not isinstance(data, dict) or (required and not data):
        raise SplitError(f"{path}: expected {'a non-empty' if required else 'an'} object of image ids")
    for k in data:
        _image_key(k, path)
    return data


def _computed_dir(split: Split, scene: Path) -> Path:
    """Where gtinfo wrote a scene's computed files: by its scene id, as BOP names scene folders."""
    return split.computed / f"{int(scene.name) if SCENE_DIR.match(scene.name) else 0:06d}"


def _read_scene(split: Split, scene: Path):
    """The images of one scene folder, each checked, in image-id order."""
    root, scene_id = split.root, int(scene.name) if SCENE_DIR.match(scene.name) else 0
    gt_path = scene / "scene_gt.json"
    gt = _scene_json(split, scene, "scene_gt.json", required=True)
    if len(gt) > MAX_IMAGES:
        raise SplitError(f"{gt_path}: more than {MAX_IMAGES:,} images in the split")
    cams = _scene_json(split, scene, "scene_camera.json") or {}
    info = _scene_json(split, scene, "scene_gt_info.json")
    computed_masks = _computed_dir(split, scene) / "mask_visib" if split.computed is not None else None
    mask_dir = computed_masks if computed_masks is not None else scene / "mask_visib" if (scene / "mask_visib").is_dir() else None
    rgb_dir = next((scene / d for d in ("rgb", "gray") if (scene / d).is_dir()), None)
    if rgb_dir is None:
        raise SplitError(f"{scene}: has no rgb/ folder")
    files = _images_in(rgb_dir, root)
    masks = _listing(mask_dir, _root_of(split, mask_dir), "mask") if mask_dir is not None else {}
    depths = _listing(scene / "depth", root, "depth image")
    for key in sorted(gt, key=int):  # every key checked by _scene_json
        im_id = int(key)
        rgb = files.get(f"{im_id:06d}")
        if rgb is None:
            raise SplitError(f"{rgb_dir}: no image {im_id:06d} (.png/.jpg/.tif) for the entry {key!r} of {gt_path.name}")
        K, w, h = _camera_of(key, cams, split.camera, scene)
        iw, ih = _image_size(rgb)
        if (w, h) != (None, None) and (iw, ih) != (w, h):
            raise SplitError(f"{rgb}: the image is {iw} x {ih} pixels, the camera says {w} x {h}")
        R_w2c = None
        if key in cams and isinstance(cams[key], dict) and "cam_R_w2c" in cams[key]:
            R_w2c = _rotation(cams[key]["cam_R_w2c"], scene / "scene_camera.json", f"{key!r}.cam_R_w2c")
        if info is not None and key not in info:
            raise SplitError(f"{_info_path(split, scene)}: no entry for image {key} (scene_gt.json has one)")
        instances = _instances(gt[key], info[key] if info is not None else None, gt_path, key,
                               _info_path(split, scene))
        mask_files = _masks_of(mask_dir, masks, im_id, len(instances)) if mask_dir is not None else ()
        depth = depths.get(f"{im_id:06d}.png")
        if depth is not None:
            _check_depth(depth, (iw, ih))
        scale = split.camera_scale
        if isinstance(cams.get(key), dict) and "depth_scale" in cams[key]:
            scale = _depth_scale(cams[key]["depth_scale"], scene / "scene_camera.json", f"{key!r}.depth_scale")
        yield SplitImage(scene_id, im_id, rgb, K, iw, ih, instances, R_w2c, mask_files, depth, scale)


def _images_in(rgb_dir: Path, root: Path) -> dict[str, Path]:
    """Image file stem -> path; two files of one image (000003.png and 000003.jpg) are refused."""
    files: dict[str, Path] = {}
    for n, p in _listing(rgb_dir, root, "image").items():
        if Path(n).suffix.lower() not in IMAGE_SUFFIXES:
            continue
        if Path(n).stem in files:
            raise SplitError(f"{p}: a second file of image {Path(n).stem} (also {files[Path(n).stem].name}); "
                             "which one is meant?")
        files[Path(n).stem] = p
    return files


def _masks_of(mask_dir: Path, masks: dict[str, Path], im_id: int, n: int) -> tuple[Path, ...]:
    """The visible mask of each of an image's ``n`` instances: a split with masks has every one."""
    names = [f"{im_id:06d}_{k:06d}.png" for k in range(n)]
    for name in names:
        if name not in masks:
            raise SplitError(f"{mask_dir / name}: mask not found (one per instance of scene_gt.json)")
    return tuple(masks[name] for name in names)


def _info_path(split: Split, scene: Path) -> Path:
    return (_computed_dir(split, scene) if split.computed is not None else scene) / "scene_gt_info.json"


def _camera_of(key: str, cams: dict, camera, scene: Path):
    if key in cams:
        K, w, h = _intrinsics(cams[key], scene / "scene_camera.json", repr(key))
        if w is None and camera is not None:
            w, h = camera[1], camera[2]
        return K, w, h
    if camera is None:
        raise SplitError(f"{scene}: image {key} has no intrinsics: no entry in scene_camera.json and no camera.json "
                         f"in {scene.parent.parent}")
    return camera


def _instances(entries, infos, gt_path: Path, key: str, info_path: Path) -> tuple[Instance, ...]:
    if not isinstance(entries, list):
        raise SplitError(f"{gt_path}: {key!r}: expected a list of instances")
    if len(entries) > MAX_INSTANCES:  # each is rendered and measured: thousands take minutes and gigabytes
        raise SplitError(f"{gt_path}: {key!r}: more than {MAX_INSTANCES} instances in one image")
    if infos is not None and (not isinstance(infos, list) or len(infos) != len(entries)):
        raise SplitError(f"{info_path}: {key!r}: expected {len(entries)} entries "
                         "(one per instance of scene_gt.json)")
    out = []
    for k, e in enumerate(entries):
        where = f"{key!r}[{k}]"
        if not isinstance(e, dict):
            raise SplitError(f"{gt_path}: {where}: expected an object")
        for name in ("obj_id", "cam_R_m2c", "cam_t_m2c"):
            if name not in e:
                raise SplitError(f"{gt_path}: {where}: missing {name}")
        obj_id = _int(e["obj_id"], gt_path, f"{where}.obj_id", 1)
        R = _numbers(e["cam_R_m2c"], 9, gt_path, f"{where}.cam_R_m2c").reshape(3, 3)
        t = _translation(e["cam_t_m2c"], gt_path, f"{where}.cam_t_m2c")
        extra = {}
        if infos is not None:
            extra = _gt_info(infos[k], info_path, where)
        out.append(Instance(obj_id, k, R, t, **extra))
    if out:
        bad = _not_rotations(np.stack([i.R_m2c for i in out]))
        if bad.any():
            raise SplitError(f"{gt_path}: {key!r}[{int(np.argmax(bad))}].cam_R_m2c: not a rotation matrix")
    return tuple(out)


def _translation(v, path: Path, where: str) -> np.ndarray:
    """``cam_t_m2c`` in metres, within MAX_DISTANCE_MM of the camera. Behind it (z <= 0) is allowed:
    BOP's PBR splits (and specsynth's) annotate every object of a scene, in view or not."""
    t = _numbers(v, 3, path, where)
    if np.linalg.norm(t) > MAX_DISTANCE_MM:
        raise SplitError(f"{path}: {where}: farther than {MAX_DISTANCE_MM:g} mm from the camera")
    return t / 1000.0


def _box(v, path: Path, where: str) -> tuple[float, ...]:
    """A BOP box [x, y, w, h], as floats (a huge integer would make numpy's arrays of Python objects)."""
    a = _numbers(v, 4, path, where)
    if np.abs(a).max() > MAX_BOX:
        raise SplitError(f"{path}: {where}: expected coordinates within {MAX_BOX:g} pixels")
    return tuple(a.tolist())


def _gt_info(e, path: Path, where: str) -> dict:
    if not isinstance(e, dict):
        raise SplitError(f"{path}: {where}: expected an object")
    try:
        return {
            "bbox_obj": _box(e["bbox_obj"], path, f"{where}.bbox_obj"),
            "bbox_visib": _box(e["bbox_visib"], path, f"{where}.bbox_visib"),
            "px_count_all": _int(e["px_count_all"], path, f"{where}.px_count_all"),
            "px_count_visib": _int(e["px_count_visib"], path, f"{where}.px_count_visib"),
            "visib_fract": _within(_number(e["visib_fract"], path, f"{where}.visib_fract"), 0.0, 1.0, path,
                                   f"{where}.visib_fract", "(a fraction)"),
        }
    except KeyError as missing:
        raise SplitError(f"{path}: {where}: missing {missing.args[0]}") from None


def check_models(split: Split, models: Path | None) -> dict[int, Path]:
    """obj_id -> model file for every object the split annotates (needed to compute masks)."""
    if models is None:
        raise SplitError(f"{split.path}: has no masks or scene_gt_info.json, and no models/ folder beside it to "
                         "compute them from (give --models)")
    models = Path(models)
    # The dataset's own models must lie inside it; a folder the user names (--models) is its own root.
    root = split.root if models == split.models else Path(os.path.realpath(models))
    out = {}
    for obj_id in split.obj_ids():
        p = models / f"obj_{obj_id:06d}.ply"
        if not p.exists():
            raise SplitError(f"{p}: no model for obj_id {obj_id}, which the split annotates")
        out[obj_id] = _regular(p, root, "model")  # a FIFO would hang the reader, a folder fail in it
    return out

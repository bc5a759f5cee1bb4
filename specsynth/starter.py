"""``specsynth init``: a commented starter spec that validates, for the user's objects and scene.

The spec is small (4 arrangements x 4 cameras at low quality: a minute or two on a laptop's CPU)
and says in comments what each block does and what to change first. It is checked by the same
compiler ``specsynth validate`` runs before it is written, so it never leaves a spec that fails.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from .plugins import installed_backend_plugins
from .spec.yamlio import Problem, SpecError, load_spec

NO_BACKEND = ("no render backend plugin is installed: install a specsynth backend distribution "
              "(in this repository: make install), then run specsynth init again")

_OBJECTS_BUILTIN = """\
objects:                       # what is dropped and annotated
  builtin: [duck, mug, teddy, lego, jenga, torus]   # built-in models (pybullet_data); for your own:
  # path: my_models/           #   a BOP models folder (obj_000001.ply ... in mm): specsynth init --models DIR
  # meshes: [{path: part.obj, unit: m}]   #   or single mesh files (PLY/OBJ/GLB/STL) with their unit
  instances: [1, 1]            # instances of each model per arrangement, [min, max]
  orientation: canonical       # canonical: upright as modelled; random: any rotation (bin picking)
  materials:
    default: {roughness: 0.5, specular: 0.5}
"""

_OBJECTS_BOP = """\
objects:                       # what is dropped and annotated
  path: {path}   # BOP models folder: obj_XXXXXX.ply in millimetres (+ models_info.json)
  # ids: [1, 5, 6]             # a subset of its objects (default: all)
  instances: [1, 1]            # instances of each model per arrangement, [min, max]
  orientation: canonical       # canonical: upright as modelled; random: any rotation (bin picking)
  materials:                   # per object id ("5"), or default for all
    default: {{roughness: 0.5, specular: 0.5}}
"""

_SCENE_BUILTIN = """\
scenes:                        # where objects are dropped: `specsynth scenes` lists the built-in ones
  - name: random_room          # a new furnished room per arrangement (furniture, textures, window, lamps)
  # - file: my_scene.glb       # or your own scene (glTF, or a scene YAML): specsynth init --scene FILE
"""

_SCENE_FILE = """\
scenes:                        # where objects are dropped
  - file: {path}   # your scene; its flat surfaces are found as stages (`specsynth scenes show FILE`)
  # - name: random_room        # add built-in scenes too (`specsynth scenes` lists them)
"""

_REST = """\
arrangements:
  count: 4                     # physics drops (each a new scene variant); raise it for a real dataset
  drop_height: [0.05, 0.5]     # metres above the stage
cameras:
  per_arrangement: 4           # images per arrangement
  azimuth: [0, 360]            # degrees around the object the camera looks at
  elevation: [15, 75]          # degrees above the stage
  distance: [0.45, 1.0]        # metres from that object's centre
visibility:
  threshold: 0.3               # a camera is kept when at least this fraction of its object is visible
quality:
  level: low                   # low: 1 sample per pixel; medium / high: denoised, the paper's error for less;
                               # paper_low ... paper_high: the paper's presets as they are (docs: quality)
backend:
  name: {backend} # the renderer: `specsynth backends` lists those installed
{look}outputs:                       # BOP, COCO and Parquet are written by default
  image_format: jpg
  depth_scale: 0.25            # mm per depth unit: uint16 then holds 16.4 m (room walls exceed 6.5 m)
"""

_HEAD = """\
# A starter dataset spec written by `specsynth init`. Check it with `specsynth validate {name}`,
# then build it: specsynth build {name} --out {out}
# Every field and its default: `specsynth schema --stdout`. Change one from the command line with
# --set FIELD=VALUE, e.g. --set cameras.per_arrangement=2 --set backend.name=NAME.
version: 1
name: {dataset}
seed: 0                        # same seed and spec: the same images, on any machine
intrinsics:                    # the camera (pixels); these are LM-O's, 640 x 480
  width: 640
  height: 480
  fx: 572.4114
  fy: 573.57043
  cx: 325.2611
  cy: 242.04899
"""


def default_backend() -> str:
    plugins = installed_backend_plugins()
    if not plugins:
        raise FileNotFoundError(NO_BACKEND)
    return min(plugins, key=lambda p: (p.default_rank, p.name)).name


def _relative(path: str, folder: Path) -> str:
    """A path given on the command line (relative to the working folder) as the spec reads it:
    relative to the spec's folder. Absolute paths and ``dataset:`` references stay as given."""
    if path.startswith("dataset:") or "${" in path or Path(path).expanduser().is_absolute():
        return path
    return Path(os.path.relpath(Path(path).resolve(), folder.resolve())).as_posix()


def _yaml_str(s: str) -> str:
    """A scalar YAML reads back as this string."""
    return s if re.fullmatch(r"[A-Za-z0-9_./:${}+-]+", s) and not s.startswith(("$", "-")) else \
        "'" + s.replace("'", "''") + "'"


def starter_text(folder: Path, *, models: str | None = None, scene: str | None = None,
                 backend: str | None = None, file_name: str = "spec.yaml") -> str:
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", folder.resolve().name).strip("._-") or "my_dataset"
    here = str(folder) == "."
    head = _HEAD.format(name=file_name if here else (folder / file_name).as_posix(), dataset=name,
                        out="out/" if here else f"{(folder / 'out').as_posix()}/")
    objects = (_OBJECTS_BOP.format(path=_yaml_str(_relative(models, folder))) if models else _OBJECTS_BUILTIN)
    scenes = _SCENE_FILE.format(path=_yaml_str(_relative(scene, folder))) if scene else _SCENE_BUILTIN
    backend = backend or default_backend()
    return head + objects + scenes + _REST.format(backend=f"{backend:<22s}", look=_look(backend))


_DENOISE = "  denoise: true                # OpenImageDenoise: at 1 sample an image is speckle without it\n"
_SENSOR = """\
sensor:                        # what the camera does to the render, as a real one does
  auto_exposure: true          # metered to middle grey: a lamp near the desk would otherwise burn it out
  auto_white_balance: true     # warm room lamps would otherwise tint every image orange
"""


def _look(backend: str) -> str:
    """What makes a path tracer's images look like photographs from the first build: its
    denoiser, and a camera that meters and balances (the photo baseline draws over photographs,
    which are exposed already)."""
    from .plugins import PluginNotFound, backend_plugin

    try:
        caps = backend_plugin(backend).capabilities
    except PluginNotFound:
        return ""
    return (_DENOISE if caps.denoise else "") + (_SENSOR if caps.draws_scene else "")


def write_starter(folder: Path, *, models: str | None = None, scene: str | None = None,
                  backend: str | None = None, file_name: str = "spec.yaml") -> Path:
    """Write ``folder/spec.yaml`` (never over an existing file) once it validates -> its path.
    Raises FileExistsError, or SpecError with the problems located in the file it would have written."""
    from .plan.compiler import compile_spec

    dest = Path(folder) / file_name
    if dest.exists() or dest.is_symlink():
        raise FileExistsError(f"{dest} exists; specsynth init never overwrites a file (give another folder)")
    text = starter_text(Path(folder), models=models, scene=scene, backend=backend, file_name=file_name)
    made = [p for p in (dest.parent, *dest.parent.parents) if not p.exists()]
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(f".{dest.name}.init.tmp")
    try:
        tmp.write_text(text)
        try:
            compile_spec(load_spec(tmp, []))
        except SpecError as e:
            tmp.unlink(missing_ok=True)
            for p in made:  # leave no empty folder behind
                p.rmdir()
            where = f"{dest} (not written)"
            raise SpecError([Problem(where, None, None, p.path, p.message) for p in e.problems]) from None
        with open(dest, "x") as f:  # "x": fails if the file appeared meanwhile, never replaces it
            f.write(text)
    finally:
        tmp.unlink(missing_ok=True)
    return dest

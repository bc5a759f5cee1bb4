"""What an output is: a per-view product or a dataset writer, and what each is given.

Outputs are plugins (``plugins.py``): a distribution registers an object in the
``specsynth.products`` or ``specsynth.writers`` entry-point group, and its name becomes the spec's
``outputs.<name>`` switch. The built-in ones (``specsynth/products/``, the writers in
``specsynth/outputs/``) are registered the same way, in specsynth's own ``pyproject.toml``.

- A **product** runs in every render job, after the colour image: it reads the image's
  :class:`View` and writes its files into the job's store folder, returning their names by kind
  (:data:`Files`). The record keeps them (``ImageRecord.files``) and every writer lays them out
  without knowing the product: BOP puts kind ``k`` in ``<chunk>/k/``, Parquet adds a column.
- A **writer** runs in the merge, once per build, over every finished image (:class:`Merge`), and
  says which files of an earlier build are its own (``owns``), so that switching it off, or
  renaming the split, removes them.

The module holding an output object is imported whenever a spec is validated: keep its top level
light (numpy, the standard library) and import what does the work inside the methods.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, Sequence

import numpy as np

from .model.ir import CameraIR, RenderResult
from .model.records import ImageRecord
from .plugins import PluginNotFound, output_plugins

if TYPE_CHECKING:  # types only: importing either at run time would cost every spec validation
    from .assets.resolve import ObjectAsset
    from .spec.models import DatasetSpec

# A product's files by kind: one file name per image, or one per instance in gt order (masks).
# Names are relative to the job's store folder; a kind is a BOP subfolder and a Parquet column.
Files = dict[str, "str | list[str]"]
ImageEntry = tuple[ImageRecord, Path]  # a record and the store folder holding its files


class View(Protocol):
    """One image as the products get it (both eyes of a stereo rig are images of their own)."""

    folder: Path  # the job's store folder for this image: write files here
    inputs: Any  # the render step's inputs (specsynth.plan.inputs.RenderInputs); products read only these
    camera: CameraIR  # the image's camera: pinhole K, world-to-camera pose (OpenCV)
    render_camera: CameraIR  # what the renderer got: the lens's wider pinhole, focus, motion
    result: RenderResult  # the backend's image (``linear`` radiance when the backend has it)
    annotation: Any  # specsynth.annotate.engine.Annotation: instances, masks, masks_visib, depth (m)
    assets: dict[int, Any]  # obj_id -> ObjectAsset of every annotated object
    rays: np.ndarray | None  # through a lens, each pixel's unit ray in the camera frame; None: K's

    def seed(self, stream: str) -> int:
        """A seed of this image's own, for ``stream`` (from the root seed and the job id only)."""

    def albedo(self) -> np.ndarray:
        """The unlit diffuse colour, HxWx3 sRGB uint8, through the lens (drawn once per image)."""

    def depth16(self) -> tuple[np.ndarray, float]:
        """The exact depth as BOP's uint16 (``value * scale = mm``) and that scale (``outputs.depth_scale``,
        or the finest that fits for 'auto'); once asked, it is the scale the image's record keeps."""

    def render_eye(self, t_w2c: Sequence[float], folder: str) -> ImageRecord:
        """Another image of this view: the same camera moved to ``t_w2c`` (metres), rendered,
        annotated and given every product's files, into ``folder`` under this image's folder."""


class ViewProduct:
    """A per-view product: files every render job writes beside the colour image."""

    name: str = ""
    description: str = ""  # one sentence: the spec reference and `specsynth outputs` show it
    default: bool = False  # on unless the spec says otherwise
    switch: bool = True  # False: no ``outputs.<name>``; ``active`` decides from other inputs
    kinds: tuple[str, ...] | None = None  # the file kinds it may write (None: its name); BOP tidies their folders
    revision: int = 1  # bump when the product's code changes its bytes: its renders re-run

    def file_kinds(self) -> tuple[str, ...]:
        return (self.name,) if self.kinds is None else self.kinds

    def active(self, inputs: Any) -> bool:
        """Whether this build's renders write it (``inputs``: RenderInputs); part of every render key."""
        return self.name in inputs.outputs.products

    def write(self, view: View) -> Files:
        """Write this image's files into ``view.folder``; their names by kind."""
        return {}

    def other_images(self, inputs: Any, t_w2c: Sequence[float]) -> dict[str, list[float]]:
        """The images this product adds to a view with ``view.render_eye`` (folder -> camera
        position), known before the view's own is drawn: the render step draws every image of a
        view first, and under ``quality.control: error`` to one schedule (a stereo pair's eyes
        then carry the same samples). An image not announced here is drawn on its own."""
        return {}

    def finish(self, record: ImageRecord, view: View) -> ImageRecord:
        """The view's record once its image is complete (called once per view, not per eye): a
        product that adds another image of the view (``view.render_eye``) links it here."""
        return record


@dataclass(frozen=True)
class Part:
    """The images of one split: the view's own (``suffix`` '') or another image of each view
    (a stereo rig's right eye: split '<split>_right', tables '*_right')."""

    split: str
    suffix: str
    images: tuple[ImageEntry, ...]  # in index order


@dataclass(frozen=True)
class Merge:
    """What every writer is given: the build's finished images and what they show."""

    out: Path  # where to write: the build's staging folder, swapped into ``final_out`` once every writer is done
    spec: DatasetSpec
    parts: tuple[Part, ...]
    models: tuple[ObjectAsset, ...]  # every obj_id the annotations name, in its own look (not objects.materials)
    enabled: frozenset[str]  # the writers switched on
    kinds: frozenset[str]  # every file kind an installed product may write, and "rgb"
    final: Path | None = None  # the dataset's folder once in place (None: ``out``)

    @property
    def final_out(self) -> Path:
        """The folder the dataset is read from: a path a file records (into the store, say) is
        relative to it, never to ``out``."""
        return self.final if self.final is not None else self.out

    @property
    def splits(self) -> set[str]:
        return {p.split for p in self.parts} | {self.spec.split}


class DatasetWriter:
    """A dataset format, written by the merge from the records and their store files."""

    name: str = ""
    description: str = ""
    default: bool = False
    needs: tuple[str, ...] = ()  # writers whose files this one reads: they must be on, and run first

    def write(self, merge: Merge) -> dict[str, int]:
        """Write (or bring up to date) this format under ``merge.out``; counts by name."""
        raise NotImplementedError

    def owns(self, rel: str, merge: Merge) -> bool | None:
        """Whether ``rel`` (a path under ``out`` that an earlier merge wrote) is this writer's:
        None, not its file; True, one it writes for this merge; False, its own but stale (a split
        no longer built). A file some writer owns and none writes now is removed."""
        return None


def products() -> dict[str, ViewProduct]:
    """Every installed product by name (a broken one raises where a spec turns it on)."""
    return _checked("product", ViewProduct)


def active_products(inputs: Any) -> list[ViewProduct]:
    """The products this build's renders write, by name."""
    return [p for _, p in sorted(products().items()) if p.active(inputs)]


def writers() -> dict[str, DatasetWriter]:
    return _checked("writer", DatasetWriter)


def in_order(found: dict[str, DatasetWriter], enabled: frozenset[str]) -> list[DatasetWriter]:
    """The enabled writers, each after those it ``needs``, otherwise by name."""
    done: list[DatasetWriter] = []

    def visit(name: str, path: tuple[str, ...]) -> None:
        if name in path:
            raise PluginNotFound(f"writers {' -> '.join(path + (name,))} need each other")
        w = found[name]
        if w in done:
            return
        for need in w.needs:
            if need in enabled:
                visit(need, path + (name,))
        done.append(w)

    for name in sorted(enabled & set(found)):
        visit(name, ())
    return done


def _checked(kind: str, base: type) -> dict:
    found, _ = output_plugins(kind)
    wrong = [n for n, obj in found.items() if not isinstance(obj, base)]
    if wrong:
        raise PluginNotFound(f"{kind} {wrong[0]!r} is not a specsynth.output_api.{base.__name__}")
    return found

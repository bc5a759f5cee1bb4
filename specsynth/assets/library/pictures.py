"""Photographs to hang on a room's walls: scikit-image's sample photographs, framed.

Rooms have pictures; a wall of flat paint is what makes a synthetic room look synthetic. These
ship inside the scikit-image wheel (a dependency of specsynth), so nothing is fetched; only the
ones whose licence is public domain or CC0 (stated in each ``skimage.data`` function's docstring)
are used, each credited in a build's attribution file.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

SOURCE = "scikit-image sample data (skimage.data)"

# name -> (file in skimage/data, author, licence); width / height from the file itself.
PICTURES: dict[str, tuple[str, str, str]] = {
    "astronaut": ("astronaut.png", "NASA", "public domain"),
    "chelsea": ("chelsea.png", "Stefan van der Walt", "CC0"),
    "coffee": ("coffee.png", "Rachel Michetti", "CC0"),
    "rocket": ("rocket.jpg", "SpaceX", "public domain"),
    "hubble_deep_field": ("hubble_deep_field.jpg", "NASA", "public domain"),
    "camera": ("camera.png", "Lav Varshney", "CC0"),
}


@dataclass(frozen=True)
class Picture:
    name: str
    path: Path
    aspect: float  # width / height
    author: str
    licence: str
    colour: bool = True  # False: a black-and-white photograph

    @property
    def credit(self) -> dict[str, str]:
        return {"asset": f"picture:{self.name}", "name": self.name, "author": self.author,
                "licence": self.licence, "source": f"{SOURCE}: {self.path.name}"}


def available() -> list[Picture]:
    """The pictures whose files are in the installed scikit-image, in a fixed order."""
    import skimage.data
    from PIL import Image

    root = Path(skimage.data.data_dir)
    out = []
    for name, (file, author, licence) in PICTURES.items():
        path = root / file
        if path.is_file():
            with Image.open(path) as im:
                out.append(Picture(name, path, im.width / im.height, author, licence, im.mode not in ("L", "LA", "1")))
    return out

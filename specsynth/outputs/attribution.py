"""``ATTRIBUTION.md`` and ``attribution.json``: every third-party asset that appears in the dataset.

CC-BY assets (most of Sweet Home 3D's furniture) require it; the others are listed too, so a
dataset's provenance is complete. Sorted by asset id, so two builds of one spec write the same
bytes. Assets come from the arrangements whose images are in the dataset: their scene's furniture
and surface textures, and the built-in objects dropped in them.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Iterable

from .dataset import write_if_changed

FIELDS = ("asset", "name", "author", "copyright", "licence", "source")


def unique_credits(credits: Iterable[dict]) -> list[dict]:
    by_asset = {c["asset"]: {k: str(c.get(k, "")) for k in FIELDS} for c in credits}
    return [by_asset[k] for k in sorted(by_asset)]


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def markdown(credits: list[dict], dataset: str) -> str:
    lines = [
        f"# Third-party assets in {dataset}",
        "",
        "Images in this dataset show the assets below. Keep this file with the dataset: CC-BY licences",
        "require the attribution it gives.",
        "",
        "| asset | name | author | copyright | licence | source |",
        "|---|---|---|---|---|---|",
    ]
    lines += ["| " + " | ".join(_md_cell(c[k]) for k in FIELDS) + " |" for c in credits]
    if not credits:
        lines.append("| (none) | | | | | |")
    return "\n".join(lines) + "\n"


def write_attribution(out: Path, credits: Iterable[dict], dataset: str) -> dict[str, int]:
    rows = unique_credits(credits)
    out = Path(out)
    write_if_changed(out / "ATTRIBUTION.md", markdown(rows, dataset).encode("utf-8"))
    write_if_changed(out / "attribution.json",
                     (json.dumps(rows, indent=1, sort_keys=True, ensure_ascii=False) + "\n").encode("utf-8"))
    return {"attribution_assets": len(rows)}

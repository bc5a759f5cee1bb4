"""The docs site: its generated pages are current, and it builds with broken links failing it."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_generated_pages_are_current():
    """docs/reference/{spec,cli}.md, docs/index.md and docs/changelog.md are what
    scripts/docs_reference.py writes from the models, the parser, README.md and CHANGELOG.md."""
    r = subprocess.run([sys.executable, str(ROOT / "scripts" / "docs_reference.py"), "--check"], capture_output=True,
                       text=True)
    assert r.returncode == 0, r.stderr


def test_every_spec_field_is_in_the_reference():
    from specsynth.spec.models import DatasetSpec

    page = (ROOT / "docs" / "reference" / "spec.md").read_text()
    for name in DatasetSpec.model_fields:
        assert f"| `{name}` |" in page, name
    assert "| `sensor.contrast` |" in page and "| `scenes.clutter` |" in page


def test_the_site_builds_strict(tmp_path):
    r = subprocess.run([str(Path(sys.executable).parent / "mkdocs"), "build", "--strict", "-d", str(tmp_path / "site")],
                       cwd=ROOT, capture_output=True, text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"})
    assert r.returncode == 0, r.stderr[-3000:]
    assert (tmp_path / "site" / "reference" / "spec" / "index.html").is_file()

"""What ``specsynth compare`` shows: a terminal table, ``compare.json`` and a PNG sheet."""

from __future__ import annotations

import io
import json
import math
from pathlib import Path

import numpy as np

from ..atomic import atomic_write_bytes
from .collect import Collected
from .comparison import STATISTICS, _column

BINS = 30
THUMB_WIDTH = 240


def histograms(synth: Collected, real: Collected) -> dict:
    """Per statistic, common bin edges over both samples (1st to 99th percentile) and the share of
    each sample per bin."""
    out = {}
    for name in STATISTICS:
        s, r = (np.asarray(_column(c, name), np.float64) for c in (synth, real))
        s, r = s[np.isfinite(s)], r[np.isfinite(r)]
        both = np.concatenate([s, r])
        if not len(both):
            continue
        lo, hi = np.percentile(both, (1, 99))
        if hi <= lo:
            lo, hi = lo - 0.5, hi + 0.5
        edges = np.linspace(lo, hi, BINS + 1)
        out[name] = {"edges": edges.tolist(),
                     "real": (np.histogram(np.clip(r, lo, hi), edges)[0] / max(len(r), 1)).tolist(),
                     "synthetic": (np.histogram(np.clip(s, lo, hi), edges)[0] / max(len(s), 1)).tolist()}
    return out


def _plain(v):
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return None if not math.isfinite(float(v)) else round(float(v), 6)
    if isinstance(v, np.integer):
        return int(v)
    return v


def to_json(result: dict) -> bytes:
    return json.dumps(_plain(result), indent=1, sort_keys=True, allow_nan=False).encode() + b"\n"


def table(result: dict, synth_name: str, real_name: str):
    from rich.table import Table

    t = Table(title=f"compare {synth_name} (synthetic, {result['images']['synthetic']} images) with {real_name} "
                    f"(real, {result['images']['real']} images)",
              caption="distance: Wasserstein-1 / real spread (IQR/1.349); <= 0.4 matches, <= 1.5 close, else differs "
                      "(docs/compare.md)")
    for col in ("group", "statistic", "synthetic median [5-95 %]", "real median [5-95 %]", "distance", "verdict"):
        t.add_column(col, justify="right" if col == "distance" else "left")
    style = {"matches": "green", "close": "yellow", "differs": "red"}
    for name, e in result["statistics"].items():
        s, r = e["synthetic"], e["real"]
        t.add_row(e["group"], name, _range(s, e["unit"]), _range(r, e["unit"]),
                  "-" if not np.isfinite(e["distance"]) else f"{e['distance']:.2f}",
                  f"[{style.get(e['verdict'], 'white')}]{e['verdict']}[/]")
    return t


def _range(s: dict, unit: str) -> str:
    if not s["n"]:
        return "-"
    f = (lambda v: f"{v:.3g}") if max(abs(s["p5"]), abs(s["p95"])) < 100 else (lambda v: f"{v:.0f}")
    return f"{f(s['median'])} [{f(s['p5'])}, {f(s['p95'])}] {unit}".strip()


def _figure_png(result: dict, hists: dict, width_px: int) -> bytes:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(hists)
    cols = 5
    rows = math.ceil(len(names) / cols)
    dpi = 100
    fig, axes = plt.subplots(rows, cols, figsize=(width_px / dpi, rows * 2.1), dpi=dpi)
    for ax in np.ravel(axes):
        ax.set_visible(False)
    for ax, name in zip(np.ravel(axes), names):
        h, e = hists[name], result["statistics"][name]
        edges = np.asarray(h["edges"])
        centres, w = (edges[:-1] + edges[1:]) / 2, np.diff(edges)
        ax.set_visible(True)
        ax.bar(centres, h["real"], width=w, color="tab:blue", alpha=0.55, label="real")
        ax.bar(centres, h["synthetic"], width=w, color="tab:orange", alpha=0.55, label="synthetic")
        d = "-" if not np.isfinite(e["distance"]) else f"{e['distance']:.2f}"
        ax.set_title(f"{name} {('(' + e['unit'] + ')') if e['unit'] else ''}: d = {d}", fontsize=9)
        ax.tick_params(labelsize=7)
        ax.set_yticks([])
    np.ravel(axes)[0].legend(fontsize=7)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    plt.close(fig)
    return buf.getvalue()


def sheet(result: dict, hists: dict, synth: Collected, real: Collected) -> bytes:
    """Histograms of every statistic, then 8 real and 8 synthetic images at one scale."""
    from PIL import Image, ImageDraw

    files = {"real": real.samples, "synthetic": synth.samples}
    sizes = [Image.open(f).size for fs in files.values() for f in fs]
    scale = THUMB_WIDTH / max((w for w, _ in sizes), default=THUMB_WIDTH)
    n = max(len(fs) for fs in files.values())
    width = max(n, 1) * THUMB_WIDTH
    rows = []
    for label, fs in files.items():
        thumbs = []
        for f in fs:
            with Image.open(f) as im:
                thumbs.append(im.convert("RGB").resize((max(1, round(im.width * scale)), max(1, round(im.height * scale)))))
        h = max((t.height for t in thumbs), default=1) + 18
        row = Image.new("RGB", (width, h), "white")
        ImageDraw.Draw(row).text((4, 2), f"{label} ({len(fs)} of {result['images'][label]} images, one scale)", fill="black")
        for k, t in enumerate(thumbs):
            row.paste(t, (k * THUMB_WIDTH, 18))
        rows.append(row)
    plot = Image.open(io.BytesIO(_figure_png(result, hists, width))).convert("RGB")
    out = Image.new("RGB", (width, plot.height + sum(r.height for r in rows)), "white")
    out.paste(plot, (0, 0))
    y = plot.height
    for r in rows:
        out.paste(r, (0, y))
        y += r.height
    buf = io.BytesIO()
    out.save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def write(out_dir: Path, result: dict, synth: Collected, real: Collected) -> list[Path]:
    """``compare.json`` (every number, histograms included) and ``compare.png`` into ``out_dir``."""
    hists = histograms(synth, real)
    out_dir = Path(out_dir)
    atomic_write_bytes(out_dir / "compare.json", to_json({**result, "histograms": hists}))
    atomic_write_bytes(out_dir / "compare.png", sheet(result, hists, synth, real))
    return [out_dir / "compare.json", out_dir / "compare.png"]

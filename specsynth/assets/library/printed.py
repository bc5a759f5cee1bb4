"""Printed matter no package gives us, drawn by code: pages, magazines, marker boards, book covers,
keyboards, screens, cardboard and posters.

Real desks are covered in paper; the LM-O test photographs show magazines, printed pages and a
board of square fiducial markers under the objects, a keyboard, a monitor showing a photograph,
boxes. Each image here is drawn with Pillow from a fixed seed per (kind, variant), so it is the
same on every machine: text is random pseudo-words set in Pillow's built-in font (Aileron Regular,
dotcolon.net, CC0), photographs are scikit-image's public-domain and CC0 samples
(``pictures.py``), credited where used. Images are written once into
``<cache>/library/printed/v<VERSION>/`` and read from there.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from ...atomic import atomic_write_bytes
from . import pictures

VERSION = 6  # 2: pages with tables and charts, LM-O-like boards, more variants. 3: open magazines, finer boards.
# 4: the boards' black at BLACK (it was 12, 0.4 % reflectance). 5: coloured paper; screens, covers and
# posters show colour photographs only; half of the posters graphic. 6: a graphic poster in one ink
# on paper or the ink's tint.
# Variants drawn per kind (a scene picks among them by its seed) and each kind's size in pixels.
VARIANTS = {"page": 24, "magazine": 24, "board": 6, "cover": 24, "keyboard": 3, "screen": 12, "cardboard": 6,
            "poster": 16}
SIZES = {"page": (620, 877), "magazine": (560, 740), "board": (980, 700), "cover": (300, 440),
         "keyboard": (880, 290), "screen": (960, 540), "cardboard": (512, 512), "poster": (600, 840)}
# Printed black: 57 of 255 (sRGB), 4 % reflectance, as toner or offset black on paper reflects (an
# optical density of about 1.4). The real LM-O photographs' marker black reads 0.09 of luma beside
# their paper's 0.85 at the strongest edges, 4.9 % apart in linear light through lmo_pbr_h's fitted
# tone curve; at 0.4 % a render's board black went to 0 there.
BLACK = 57
# Coloured copier paper (sRGB): yellow, orange, pink, green, blue; a share of the pages is printed on
# it. The desks of the LM-O test photographs have yellow sheets and red and orange prints; their
# strongly coloured pixels are mostly yellow and red (docs/realism.md), and white paper gave none.
PAPER_COLOURS = ((252, 234, 105), (250, 196, 118), (245, 186, 196), (192, 230, 168), (176, 208, 240))
COLOURED_PAPER = 0.3
# Process-ink colours (sRGB) that graphic posters are laid out in: the inks' primaries and their
# two-ink mixes, as printed colour fields come out; and paper white and black.
PRINT_COLOURS = ((250, 220, 0), (230, 0, 126), (0, 160, 227), (226, 30, 36), (0, 150, 64), (45, 46, 131),
                 (244, 244, 240), (30, 30, 30))
INKS, PAPER_WHITE = PRINT_COLOURS[:6], PRINT_COLOURS[6]
# A tint: the ink screened to this share of the paper, as a lighter field of the same colour prints.
TINT = 0.45
KIND_CODE = {k: i for i, k in enumerate(sorted(VARIANTS))}
FONT_CREDIT = {"asset": "font:aileron", "name": "Aileron Regular (the font built into Pillow)",
               "author": "Sora Sagano (dotcolon.net)", "licence": "CC0-1.0", "source": "Pillow"}


class PrintedError(ValueError):
    """An unknown kind or variant."""


@dataclass(frozen=True)
class Printed:
    kind: str
    index: int
    path: Path
    aspect: float  # width / height
    credits: tuple[dict, ...]


def _font(size: int):
    from PIL import ImageFont

    return ImageFont.load_default(size=size)


def _words(rng, n: int) -> list[str]:
    """Pseudo-words of letters drawn with English-like frequencies: text at a glance, no text of anyone's."""
    letters = "etaoinshrdlcumwfgypbvk"
    p = np.linspace(2.0, 0.4, len(letters))
    p /= p.sum()
    return ["".join(rng.choice(list(letters), size=int(rng.integers(2, 10)), p=p)) for _ in range(n)]


def _photograph(rng, size: tuple[int, int], colour: bool = False):
    """A crop of one of the sample photographs filling ``size`` -> (image, its credit); ``colour``:
    of the colour ones only (a screen or a cover shows no black-and-white photograph)."""
    from PIL import Image

    pics = [p for p in pictures.available() if p.colour or not colour]
    pic = pics[int(rng.integers(len(pics)))]
    with Image.open(pic.path) as im:
        im = im.convert("RGB")
        w, h = size
        scale = max(w / im.width, h / im.height) * float(rng.uniform(1.0, 1.6))
        im = im.resize((max(w, int(im.width * scale)), max(h, int(im.height * scale))), Image.BILINEAR)
        x, y = int(rng.integers(0, im.width - w + 1)), int(rng.integers(0, im.height - h + 1))
        return im.crop((x, y, x + w, y + h)), pic.credit


def _colour(rng, lo: float = 0.0, hi: float = 1.0) -> tuple[int, int, int]:
    import colorsys

    r, g, b = colorsys.hsv_to_rgb(float(rng.random()), float(rng.uniform(0.35, 0.95)), float(rng.uniform(lo, hi)))
    return int(r * 255), int(g * 255), int(b * 255)


def _text_block(draw, rng, x0: int, y0: int, x1: int, y1: int, size: int, ink) -> None:
    font = _font(size)
    y = y0
    while y + size < y1:
        x = x0
        for word in _words(rng, 14):
            w = int(draw.textlength(word, font=font))
            if x + w > x1:
                break
            draw.text((x, y), word, fill=ink, font=font)
            x += w + size // 3
        y += int(size * 1.45)
        if rng.random() < 0.08:
            y += size  # a paragraph break


def _page(rng, size):
    """A printed page: a title, text, and often a figure, a table or a chart at the scale of the page."""
    from PIL import Image, ImageDraw

    w, h = size
    tint = int(rng.integers(232, 252))
    paper = (tint, tint, int(tint - rng.integers(0, 10)))
    if rng.random() < COLOURED_PAPER:
        paper = PAPER_COLOURS[int(rng.integers(len(PAPER_COLOURS)))]
    im = Image.new("RGB", size, paper)
    d = ImageDraw.Draw(im)
    m = int(w * 0.1)
    ink = tuple(int(v) for v in rng.integers(10, 60, 3))
    d.text((m, m), " ".join(_words(rng, 4)).title(), fill=ink, font=_font(int(h * 0.035)))
    y = m + int(h * 0.07)
    credits = []
    while y < h - m - int(h * 0.1):
        what = rng.choice(["text", "text", "figure", "table", "chart"])
        bh = int(h * rng.uniform(0.12, 0.25))
        if what == "figure":
            picture, credit = _photograph(rng, (w - 2 * m, bh))
            im.paste(picture, (m, y))
            credits.append(credit)
        elif what == "table":
            rows, cols = int(rng.integers(4, 9)), int(rng.integers(2, 5))
            for r in range(rows + 1):
                yy = y + r * bh // rows
                d.line((m, yy, w - m, yy), fill=ink, width=2 if r in (0, 1, rows) else 1)
            for c in range(cols):
                for r in range(rows):
                    d.text((m + 6 + c * (w - 2 * m) // cols, y + 3 + r * bh // rows), _words(rng, 1)[0],
                           fill=ink, font=_font(max(9, bh // rows - 8)))
        elif what == "chart":
            n = int(rng.integers(4, 10))
            colour = _colour(rng, 0.4, 0.9)
            bw = (w - 2 * m) // n
            for k in range(n):
                top = y + int(bh * rng.uniform(0.05, 0.9))
                d.rectangle((m + k * bw + 3, top, m + (k + 1) * bw - 3, y + bh), fill=colour)
            d.line((m, y + bh, w - m, y + bh), fill=ink, width=2)
        else:
            _text_block(d, rng, m, y, w - m, y + bh, int(h * 0.014), ink)
        y += bh + int(h * 0.03)
    return im, credits


def _magazine(rng, size):
    """A cover (a photograph, a title, headlines, a barcode) or, as often, a magazine lying open:
    columns of text round photographs, headings and coloured boxes, as the magazines on the LM-O
    desk show."""
    return _cover_page(rng, size) if rng.random() < 0.5 else _spread(rng, size)


def _spread(rng, size):
    from PIL import Image, ImageDraw

    w, h = size
    tint = int(rng.integers(225, 250))
    im = Image.new("RGB", size, (tint, tint, int(tint - rng.integers(0, 12))))
    d = ImageDraw.Draw(im)
    credits = []
    ink = tuple(int(v) for v in rng.integers(10, 50, 3))
    m, cols = int(w * 0.06), int(rng.integers(2, 4))
    col_w = (w - 2 * m) // cols
    d.text((m, m), " ".join(_words(rng, 3)).title(), fill=_colour(rng, 0.2, 0.7), font=_font(int(h * 0.05)))
    for c in range(cols):
        x0, x1 = m + c * col_w + 6, m + (c + 1) * col_w - 6
        y = m + int(h * 0.09)
        while y < h - m - int(h * 0.06):
            bh = int(h * rng.uniform(0.1, 0.3))
            what = rng.choice(["text", "text", "picture", "box"])
            if what == "picture":
                picture, credit = _photograph(rng, (x1 - x0, bh))
                im.paste(picture, (x0, y))
                credits.append(credit)
            elif what == "box":
                d.rectangle((x0, y, x1, y + bh), fill=_colour(rng, 0.5, 1.0))
                _text_block(d, rng, x0 + 6, y + 6, x1 - 6, y + bh - 4, int(h * 0.017), ink)
            else:
                _text_block(d, rng, x0, y, x1, min(y + bh, h - m), int(h * 0.017), ink)
            y += bh + int(h * 0.02)
    return im, credits


def _cover_page(rng, size):
    from PIL import ImageDraw

    w, h = size
    im, credit = _photograph(rng, size, colour=True)
    d = ImageDraw.Draw(im)
    title = _words(rng, 1)[0].upper()[:7]
    colour = _colour(rng, 0.7, 1.0)
    d.text((int(w * 0.05), int(h * 0.02)), title, fill=colour, font=_font(int(h * 0.12)))
    for k in range(int(rng.integers(2, 5))):
        y = int(h * (0.55 + 0.1 * k))
        band = _colour(rng, 0.2, 1.0)
        text = " ".join(_words(rng, 3)).upper()
        d.rectangle((int(w * 0.04), y, int(w * 0.04) + int(d.textlength(text, font=_font(int(h * 0.035)))) + 8,
                     y + int(h * 0.05)), fill=band)
        d.text((int(w * 0.04) + 4, y + 2), text, fill=(255, 255, 255), font=_font(int(h * 0.035)))
    for k in range(30):  # a barcode
        x = int(w * 0.78) + 3 * k
        if rng.random() < 0.6:
            d.rectangle((x, int(h * 0.9), x + 1, int(h * 0.97)), fill=(0, 0, 0))
    return im, [credit]


def _board(rng, size):
    """A board of square fiducial markers round a free middle, as under the LM-O objects: 9 x 7
    cells, each a black square with a white glyph of 4 x 4 random bits."""
    from PIL import Image, ImageDraw

    w, h = size
    paper = (246, 246, 243)
    im = Image.new("RGB", size, paper)
    d = ImageDraw.Draw(im)
    cols, rows, n = 9, 7, 4
    cell = min(w // cols, h // rows)
    ox, oy = (w - cols * cell) // 2, (h - rows * cell) // 2
    for r in range(rows):
        for c in range(cols):
            if 0 < r < rows - 1 and 0 < c < cols - 1:
                continue  # the markers ring the board; the middle stays white
            x, y = ox + c * cell, oy + r * cell
            pad = cell // 10
            d.rectangle((x + pad, y + pad, x + cell - pad, y + cell - pad), fill=(BLACK, BLACK, BLACK))
            bits = rng.random((n, n)) < 0.5
            bits[n // 2, n // 2] = True  # every glyph has a white bit, so none is all black
            s = (cell - 2 * pad) / (n + 2)
            for i in range(n):
                for j in range(n):
                    if bits[i, j]:
                        d.rectangle((x + pad + (j + 1) * s, y + pad + (i + 1) * s, x + pad + (j + 2) * s - 1,
                                     y + pad + (i + 2) * s - 1), fill=paper)
    return im, []


def _cover(rng, size):
    from PIL import Image, ImageDraw

    w, h = size
    im = Image.new("RGB", size, _colour(rng, 0.15, 0.9))
    d = ImageDraw.Draw(im)
    band = _colour(rng, 0.5, 1.0)
    y = int(h * rng.uniform(0.15, 0.55))
    d.rectangle((0, y, w, y + int(h * 0.16)), fill=band)
    ink = (250, 250, 250) if sum(band) < 380 else (20, 20, 20)
    d.text((int(w * 0.08), y + int(h * 0.03)), " ".join(_words(rng, 2)).title(), fill=ink, font=_font(int(h * 0.06)))
    d.text((int(w * 0.08), int(h * 0.88)), " ".join(_words(rng, 2)).title(), fill=ink, font=_font(int(h * 0.04)))
    return im, []


def _keyboard(rng, size):
    from PIL import Image, ImageDraw

    w, h = size
    dark = rng.random() < 0.7
    body, cap, ink = ((30, 30, 32), (48, 48, 52), (200, 200, 200)) if dark else ((210, 210, 212), (240, 240, 240), (60, 60, 60))
    im = Image.new("RGB", size, body)
    d = ImageDraw.Draw(im)
    rows = ["1234567890", "qwertyuiop", "asdfghjkl", "zxcvbnm"]
    key = w // 19
    font = _font(int(key * 0.4))
    for r, row in enumerate(rows):
        y = int(h * 0.12) + r * int(key * 1.1)
        x = int(w * 0.04) + r * key // 3
        for ch in row:
            d.rounded_rectangle((x, y, x + key - 4, y + key - 4), radius=4, fill=cap)
            d.text((x + key * 0.3, y + key * 0.2), ch.upper(), fill=ink, font=font)
            x += key
    y = int(h * 0.12) + 4 * int(key * 1.1)
    d.rounded_rectangle((int(w * 0.2), y, int(w * 0.55), y + key - 4), radius=4, fill=cap)  # the space bar
    for k in range(4):  # the number pad
        for j in range(3):
            x0, y0 = int(w * 0.8) + j * key, int(h * 0.12) + k * int(key * 1.1)
            d.rounded_rectangle((x0, y0, x0 + key - 4, y0 + key - 4), radius=4, fill=cap)
    return im, []


def _screen(rng, size):
    from PIL import ImageDraw

    w, h = size
    im, credit = _photograph(rng, size, colour=True)
    d = ImageDraw.Draw(im)
    for _ in range(int(rng.integers(0, 3))):  # windows
        x0, y0 = int(rng.uniform(0.05, 0.5) * w), int(rng.uniform(0.05, 0.4) * h)
        x1, y1 = x0 + int(rng.uniform(0.3, 0.5) * w), y0 + int(rng.uniform(0.3, 0.5) * h)
        d.rectangle((x0, y0, x1, y1), fill=(248, 248, 248))
        d.rectangle((x0, y0, x1, y0 + 18), fill=_colour(rng, 0.4, 0.8))
        _text_block(d, rng, x0 + 10, y0 + 28, x1 - 10, y1 - 8, 11, (30, 30, 30))
    d.rectangle((0, h - 24, w, h), fill=(25, 25, 30))  # a task bar
    return im, [credit]


def _cardboard(rng, size):
    from PIL import Image, ImageDraw, ImageFilter

    w, h = size
    base = np.array([int(rng.integers(150, 190)), int(rng.integers(110, 140)), int(rng.integers(70, 95))], np.float32)
    fibre = rng.normal(0, 1, (h, w)).astype(np.float32)
    fibre = np.asarray(Image.fromarray(((fibre * 40) + 128).clip(0, 255).astype(np.uint8)).filter(
        ImageFilter.GaussianBlur(1.2)), np.float32) / 128.0 - 1.0
    px = np.clip(base[None, None] * (1.0 + 0.12 * fibre[..., None]), 0, 255).astype(np.uint8)
    im = Image.fromarray(px, "RGB")
    d = ImageDraw.Draw(im)
    tape = (int(rng.integers(170, 220)),) * 3 if rng.random() < 0.5 else (190, 160, 110)
    x = int(w * rng.uniform(0.35, 0.55))
    d.rectangle((x, 0, x + int(w * 0.12), h), fill=tape)
    d.text((int(w * 0.08), int(h * 0.7)), _words(rng, 1)[0].upper(), fill=(40, 30, 25), font=_font(int(h * 0.08)))
    return im, []


def _poster(rng, size):
    """Half of them a photograph with a coloured band and a title; the others graphic, as
    advertisements and magazine covers are: paper or a tint with a field of one printing ink, a
    photograph in a frame, a title and lines of text. One ink, as posters of two or three inks side
    by side (yellow beside blue) made lmo_pbr_h's closest views more colourful than any real LM-O
    photograph (docs/realism.md)."""
    return _photo_poster(rng, size) if rng.random() < 0.5 else _graphic_poster(rng, size)


def _photo_poster(rng, size):
    from PIL import ImageDraw

    w, h = size
    im, credit = _photograph(rng, size, colour=True)
    d = ImageDraw.Draw(im)
    d.rectangle((0, int(h * 0.8), w, h), fill=_colour(rng, 0.1, 0.6))
    d.text((int(w * 0.06), int(h * 0.83)), " ".join(_words(rng, 2)).upper(), fill=(250, 250, 250),
           font=_font(int(h * 0.06)))
    return im, [credit]


def tint(ink: tuple[int, int, int]) -> tuple[int, int, int]:
    """``ink`` screened to TINT on PAPER_WHITE."""
    return tuple(int(round(TINT * i + (1 - TINT) * p)) for i, p in zip(ink, PAPER_WHITE))


def _graphic_poster(rng, size):
    from PIL import Image, ImageDraw

    w, h = size
    ink = INKS[int(rng.integers(len(INKS)))]
    ground = (PAPER_WHITE, tint(ink))[int(rng.integers(2))]
    im = Image.new("RGB", size, ground)
    d = ImageDraw.Draw(im)
    across = float(rng.uniform(0.15, 0.4))  # a field of the ink from an edge
    box = [(0, 0, w, int(h * across)), (0, int(h * (1 - across)), w, h), (0, 0, int(w * across), h),
           (int(w * (1 - across)), 0, w, h)][int(rng.integers(4))]
    d.rectangle(box, fill=ink)
    x0, y0 = int(w * rng.uniform(0.08, 0.3)), int(h * rng.uniform(0.2, 0.45))
    pw, ph = int(w * rng.uniform(0.45, 0.62)), int(h * rng.uniform(0.25, 0.4))
    picture, credit = _photograph(rng, (pw, ph), colour=True)
    im.paste(picture, (x0, y0))
    text = (20, 20, 20)  # on paper or a tint, both light
    d.text((int(w * 0.06), int(h * 0.04)), _words(rng, 1)[0].upper()[:8], fill=text, font=_font(int(h * 0.1)))
    _text_block(d, rng, int(w * 0.06), int(h * 0.78), int(w * 0.94), int(h * 0.96), int(h * 0.025), text)
    return im, [credit]


DRAW = {"page": _page, "magazine": _magazine, "board": _board, "cover": _cover, "keyboard": _keyboard,
        "screen": _screen, "cardboard": _cardboard, "poster": _poster}


def folder(cache: Path) -> Path:
    return Path(cache) / "library" / "printed" / f"v{VERSION}"


@lru_cache(maxsize=512)
def printed(cache: Path, kind: str, index: int) -> Printed:
    """Variant ``index`` of a kind, drawn into the cache on first use."""
    if kind not in VARIANTS:
        raise PrintedError(f"no printed kind {kind!r}; kinds: {', '.join(sorted(VARIANTS))}")
    index = int(index) % VARIANTS[kind]
    rng = np.random.default_rng([VERSION, KIND_CODE[kind], index])
    path = folder(cache) / f"{kind}_{index:02d}.png"
    credits_path = path.with_suffix(".json")
    if not (path.is_file() and credits_path.is_file()):
        im, credits = DRAW[kind](rng, SIZES[kind])
        buf = io.BytesIO()
        im.save(buf, format="PNG")
        atomic_write_bytes(path, buf.getvalue())
        font = [] if kind == "board" else [FONT_CREDIT]  # the board has no text
        atomic_write_bytes(credits_path, json.dumps(font + credits).encode())
    credits = tuple(json.loads(credits_path.read_text()))
    w, h = SIZES[kind]
    return Printed(kind, index, path, w / h, credits)

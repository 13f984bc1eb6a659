"""The contact sheet of a batch: one PNG, a grid of the jobs' still pictures (front, back and side of each drape,
taichi_cloth.still), each cell labelled with the job and its status (green: ok; red: anything else). A job
without a picture (it failed before drawing one) gets a grey cell with its reason."""
from __future__ import annotations

import math
from pathlib import Path

SHEET = "contact_sheet.png"
#: a cell's picture width [px] (the still is scaled down to it) and the label's height below it
CELL_W, LABEL_H, PAD = 480, 46, 8
BACKGROUND, OK_RGB, BAD_RGB, GREY = (30, 31, 34), (120, 210, 130), (240, 110, 100), (70, 72, 78)


def write_sheet(rows: list[dict], jobs_dirs: dict, path: str | Path, title: str) -> Path:
    """Write the sheet of `rows` (in job order) at `path`. jobs_dirs: {key: the job's folder}. Returns the path."""
    from PIL import Image, ImageDraw, ImageFont  # matplotlib's image library: only when the sheet is drawn

    thumbs = []
    for row in rows:
        still = next((n for n in (row.get("outputs") or "").split() if n == f"{row['label']}.png"), None)
        image = None
        if still is not None:
            try:
                with Image.open(Path(jobs_dirs[row["key"]]) / still) as im:
                    image = im.convert("RGB")
                    image.thumbnail((CELL_W, CELL_W))
            except OSError:
                image = None
        thumbs.append(image)
    cell_h = max([t.height for t in thumbs if t is not None] or [CELL_W // 3])
    cols = max(1, min(len(rows), math.ceil(math.sqrt(len(rows) * 1.5))))
    nrows = math.ceil(len(rows) / cols) if rows else 1
    font = ImageFont.load_default(size=15)
    title_h = 36
    sheet = Image.new("RGB", (cols * (CELL_W + PAD) + PAD, title_h + nrows * (cell_h + LABEL_H + PAD) + PAD),
                      BACKGROUND)
    draw = ImageDraw.Draw(sheet)
    draw.text((PAD, 8), title, fill=(235, 235, 235), font=ImageFont.load_default(size=20))
    for k, (row, thumb) in enumerate(zip(rows, thumbs)):
        x = PAD + (k % cols) * (CELL_W + PAD)
        y = title_h + (k // cols) * (cell_h + LABEL_H + PAD)
        if thumb is not None:
            sheet.paste(thumb, (x + (CELL_W - thumb.width) // 2, y + (cell_h - thumb.height) // 2))
        else:
            draw.rectangle((x, y, x + CELL_W - 1, y + cell_h - 1), fill=GREY)
            draw.text((x + 8, y + 8), _fit(row.get("reason") or "no picture", draw, font, CELL_W - 16),
                      fill=(220, 220, 220), font=font)
        ok = row["status"] == "ok"
        draw.text((x, y + cell_h + 4), _fit(row["label"], draw, font, CELL_W), fill=(235, 235, 235), font=font)
        status = row["status"] + ("" if ok else f": {row.get('reason') or ''}")
        draw.text((x, y + cell_h + 23), _fit(status, draw, font, CELL_W), fill=OK_RGB if ok else BAD_RGB, font=font)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path, format="png")
    return path


def _fit(text: str, draw, font, width: int) -> str:
    """`text`, cut with an ellipsis to fit `width` pixels."""
    if draw.textlength(text, font=font) <= width:
        return text
    while text and draw.textlength(text + "...", font=font) > width:
        text = text[:-1]
    return text + "..."

"""``boxes_csv``: ``csv/<split>.csv``, one row per visible object (image index, gt id, obj_id, the
COCO-convention visible box, visible fraction), for a spreadsheet or a quick look."""

from __future__ import annotations

from specsynth.output_api import DatasetWriter, Merge
from specsynth.outputs.dataset import coco_box, write_if_changed

HEADER = "index,gt_id,obj_id,x,y,w,h,visib_fract\n"


class BoxesCsv(DatasetWriter):
    name = "boxes_csv"
    description = "A CSV of visible boxes per split (COCO's box convention), into csv/<split>.csv."

    def write(self, merge: Merge) -> dict[str, int]:
        rows = 0
        for part in merge.parts:
            lines = [HEADER]
            for rec, _ in part.images:
                for gt_id, g in enumerate(rec.instances):
                    if g.px_count_visib < 1:
                        continue
                    x, y, w, h = coco_box(g.bbox_visib)
                    lines.append(f"{rec.index},{gt_id},{g.obj_id},{x},{y},{w},{h},{g.visib_fract:.6f}\n")
            write_if_changed(merge.out / "csv" / f"{part.split}.csv", "".join(lines).encode())
            rows += len(lines) - 1
        return {"csv_rows": rows}

    def owns(self, rel: str, merge: Merge) -> bool | None:
        parts = rel.split("/")
        if len(parts) == 2 and parts[0] == "csv" and parts[1].endswith(".csv"):
            return parts[1].removesuffix(".csv") in merge.splits
        return None


WRITER = BoxesCsv()

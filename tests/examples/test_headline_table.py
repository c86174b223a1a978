"""The headline table (examples/headline.py): imagers named by their files, seeds pooled, ratios to single."""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from pathlib import Path

from factories import example_script

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "examples" / "headline.py"


def _module():
    return example_script("headline")


def _row(file, model, f1_3d, f1_2d, com=1.0, row="file"):
    return {"row": row, "file": file, "model": model, "set": "x", "f1_micro_3d": f1_3d, "f1_micro_2d": f1_2d,
            "com_error_mm_2d": com, "com_error_mm_3d": com, "diameter_error_mm_2d": None,
            "diameter_error_mm_3d": 2.0}


def _records(tmp_path):
    rows = [_row(f"w/pred_img_less_s{s}_on_single.npz", "less", f, f + 0.1) for s,
            f in enumerate((0.5, 0.6, 0.7))]
    rows += [_row(f"w/pred_img_less_s{s}_on_multiple.npz", "less", f, f) for s,
             f in enumerate((0.3, 0.3, 0.6))]
    rows += [_row("w/pred_forcemap_on_single.npz", "forcemap", 0.4, 0.5),
             _row("w/pred_forcemap_on_single.npz", "average", None, None, com=9.0),
             # group rows: ignored
             _row("w/pred_img_less_s0_on_single.npz", "less", 0.99, 0.99, row="group")]
    path = tmp_path / "acc.jsonl"
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def test_seeds_of_one_imager_pool_into_mean_and_spread(tmp_path):
    groups = _module().read_groups(str(_records(tmp_path)))
    single = groups[("single", "less")]
    assert single["n"] == 3 and single["f1_micro_3d"] == statistics.fmean([0.5, 0.6, 0.7])
    assert single["f1_micro_3d_std"] == statistics.stdev([0.5, 0.6, 0.7])
    assert "diameter_error_mm_2d" not in single and single["diameter_error_mm_3d"] == 2.0
    assert groups[("single", "average")]["n"] == 1 and groups[("single", "average")]["com_error_mm_2d"] == 9.0
    assert set(groups) == {("single", "less"), ("multiple", "less"), ("single", "forcemap"),
                           ("single", "average")}


def test_the_table_leads_with_2d_and_gives_each_imager_its_ratio(tmp_path):
    out = subprocess.run([sys.executable, str(SCRIPT), str(_records(tmp_path))], capture_output=True,
                         text=True, check=True).stdout
    header = next(line for line in out.splitlines() if line.startswith("| set |"))
    assert header.split("|")[3].strip() == "2D F1"
    ratio = next(line for line in out.splitlines() if line.startswith("| less |"))
    assert ratio.split("|")[2].strip() == f"{0.4 / 0.7:.2f}"          # 2D multiple / single, seed means
    assert ratio.split("|")[4].strip() == f"{0.4 / 0.6:.2f}"          # 3D
    assert "| single | less | 0.835 |" in out                           # the paper's numbers
    assert "| classical (n=1) |" in out and "| average (n=1) | - |" in out
    quiet = subprocess.run([sys.executable, str(SCRIPT), str(_records(tmp_path)), "--no-paper"],
                           capture_output=True, text=True, check=True).stdout
    assert "paper" not in quiet


def test_other_imagers_follow_the_headlines_with_their_numbers_in_order_of_value():
    names = ["global-n1344-same", "less", "global-n888-all", "global-n168", "average", "global-n168-d64"]
    groups = {("val", n): {} for n in names}
    assert _module().imagers(groups) == ["less", "average", "global-n168", "global-n168-d64",
                                         "global-n888-all", "global-n1344-same"]


def test_a_study_scored_on_one_set_has_no_ratio_section_and_imagers_without_ratios_get_no_row(tmp_path):
    rows = [_row("w/pred_img_less_s0_on_val.npz", "less", 0.5, 0.6)]
    (tmp_path / "val.jsonl").write_text("".join(json.dumps({**r, "set": "validation"}) + "\n" for r in rows))
    out = subprocess.run([sys.executable, str(SCRIPT), str(tmp_path / "val.jsonl"), "--no-paper"],
                         capture_output=True, text=True, check=True).stdout
    assert "| validation | less (n=1) | 0.600 |" in out and "Generalisation" not in out
    full = subprocess.run([sys.executable, str(SCRIPT), str(_records(tmp_path))], capture_output=True,
                          text=True, check=True).stdout
    assert "| less |" in full and "| forcemap |" not in full            # forcemap was scored on single only

"""Tables are for people: long list and mapping cells are cut, saying how many items there are, and one wide
record is written down the page; the JSON formats keep everything."""

import json

import pytest
from factories import random_scanset

from lesscli.io.records import CELL_ITEMS_WIDTH, TABLE_WIDTH, format_table
from lesscli.io.scans import save_scans


@pytest.mark.parametrize("value, cell", [
    (["x", "y"], '["x", "y"]'),                                                   # short: whole
    ([f"R{i}s0" for i in range(102)], '["R0s0", "R1s0", "R2s0", "R3s0", "R4s0", ... (102 in all)]'),
    ({f"k{i}": i for i in range(40)}, '{"k0": 0, "k1": 1, "k2": 2, "k3": 3, ... (40 in all)}'),
    # an item cut to the room left
    (["a" * 80], '["' + "a" * 53 + '..."]'),
    (["a" * 80, "b"], '["' + "a" * 37 + '...", ... (2 in all)]'),
    ([{"name": "St8C5", "shape": [13, 64, 64], "origin_mm": [-11.0, -30.2, -30.2]}] * 3,
     '[{"name": "St8C5", ... (3 in all)}, ... (3 in all)]'),                      # items of items cut too
    # rounded as number cells are
    ([0.123456789, 2.0, float("nan")], "[0.1235, 2.0, null]"),
    ([], "[]"),
])
def test_a_list_cell_is_cut_to_its_first_items(value, cell):
    assert format_table([{"v": value}, {"v": 0}]).splitlines()[2].strip() == cell
    assert len(cell) <= CELL_ITEMS_WIDTH


def test_one_wide_record_is_written_down_the_page():
    record = {"file": "/data/" + "x" * 60 + ".npz", **{f"count_{i}": i for i in range(12)},
              "names": [f"Insert{i:03d}" for i in range(30)]}
    lines = format_table([record]).splitlines()
    assert lines[0].split() == ["key", "value"] and len(lines) == 2 + len(record)
    assert lines[2].split() == ["file", record["file"]] and lines[5].split() == ["count_2", "2"]
    assert max(map(len, lines)) <= TABLE_WIDTH and "(30 in all)" in lines[-1]
    # the value column is wider than a cell
    assert lines[-1].count("Insert") > CELL_ITEMS_WIDTH // 11
    # a document's table: columns
    markdown = format_table([record], markdown=True).splitlines()
    assert len(markdown) == 3 and markdown[0].split("|")[1].strip() == "file" and "(30 in all)" in markdown[2]
    narrow = format_table([{"scans": 32, "steps": 5315}]).splitlines()
    assert narrow[0].split() == ["scans", "steps"]                       # a narrow record stays a row
    assert len(format_table([record, record]).splitlines()) == 4         # several records stay rows


def test_split_table_cuts_the_insert_names_and_json_keeps_them(run_less, tmp_path):
    names = [f"Insert{i:03d}" for i in range(40)]
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=40, traj_per_scan=1, inserts=names))
    args = ("split", "s.npz", "--test", "0.25", "--seed", "0", "-o", "out")
    table = run_less(*args, "--format", "table", check=True).stdout.decode().splitlines()
    assert max(len(line) for line in table) < 200
    assert "(30 in all)" in table[2] and "(10 in all)" in table[3]
    rows = [json.loads(line)
            for line in run_less(*args, "--format", "jsonl", check=True).stdout.decode().splitlines()]
    assert sorted(rows[0]["inserts"] + rows[1]["inserts"]) == names
    info = run_less("info", "s.npz", "--format", "table", check=True).stdout.decode().splitlines()
    assert info[0].split() == ["key", "value"] and max(map(len, info)) <= TABLE_WIDTH
    assert json.loads(run_less("info", "s.npz", "--format", "jsonl", check=True).stdout)["inserts"] == names


def test_records_of_several_kinds_make_a_table_each():
    import io

    from lesscli.io.records import emit_records

    rows = [{"row": "contrast", "air": 0.04, "silicone": 0.41},
            {"row": "class", "class": "insert", "voxels": 7},
            {"row": "class", "class": "pillar", "voxels": 3}, {"row": "pillar", "diameter_mm": 4.01}]
    out = io.StringIO()
    emit_records(rows, "table", out)
    tables = [t.splitlines() for t in out.getvalue().strip().split("\n\n")]
    assert [t[0].split() for t in tables] == [["row", "air", "silicone"], ["row", "class", "voxels"],
                                              ["row", "diameter_mm"]]
    assert [len(t) for t in tables] == [3, 4, 3]
    out = io.StringIO()
    emit_records(rows, "table", out, columns=["row", "voxels"])        # columns given: one table
    assert "\n\n" not in out.getvalue() and len(out.getvalue().splitlines()) == 6
    out = io.StringIO()
    emit_records(rows, "jsonl", out)
    assert [json.loads(line) for line in out.getvalue().splitlines()] == rows

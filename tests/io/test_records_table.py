"""Tables are for people: long list and mapping cells are cut with how many items there are; JSON keeps all."""

import json

import pytest
from factories import random_scanset

from lesscli.io.records import CELL_ITEMS_WIDTH, format_table
from lesscli.io.scans import save_scans


@pytest.mark.parametrize("value, cell", [
    (["x", "y"], '["x", "y"]'),                                                   # short: whole
    ([f"R{i}s0" for i in range(102)], '["R0s0", "R1s0", "R2s0", "R3s0", "R4s0", ... (102 in all)]'),
    ({f"k{i}": i for i in range(40)}, '{"k0": 0, "k1": 1, "k2": 2, "k3": 3, ... (40 in all)}'),
    (["a" * 80], '["' + "a" * 80 + '"]'),                                          # one wide item: nothing to cut
    (["a" * 80, "b"], '["' + "a" * 80 + '", ... (2 in all)]'),
    ([0.123456789, 2.0, float("nan")], "[0.1235, 2.0, null]"),                    # rounded as number cells are
    ([], "[]"),
])
def test_a_list_cell_is_cut_to_its_first_items(value, cell):
    row = format_table([{"v": value}]).splitlines()[2]
    assert row.strip() == cell
    assert len(cell) <= CELL_ITEMS_WIDTH or "a" * 80 in cell      # within the width but for one wide item


def test_split_table_cuts_the_insert_names_and_json_keeps_them(run_less, tmp_path):
    names = [f"Insert{i:03d}" for i in range(40)]
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=40, traj_per_scan=1, inserts=names))
    args = ("split", "s.npz", "--test", "0.25", "--seed", "0", "-o", "out")
    table = run_less(*args, "--format", "table", check=True).stdout.decode().splitlines()
    assert max(len(line) for line in table) < 200
    assert "(30 in all)" in table[2] and "(10 in all)" in table[3]
    rows = [json.loads(line) for line in run_less(*args, "--format", "jsonl", check=True).stdout.decode().splitlines()]
    assert sorted(rows[0]["inserts"] + rows[1]["inserts"]) == names

"""``less import ARCHIVE.zip`` reads the published zip in place and gives what the extracted folder gives."""

import json
import os
import zipfile

import numpy as np
import pytest
from published_fixture import write_hand_held_root, write_root, zip_root

from lesscli.data.published import ImportOptions, import_published
from lesscli.data.sources import MemberView, ZipSource
from lesscli.errors import DataError


def _arrays_and_meta(path):
    """Every array of a saved scan set, and its meta without the history (command line and time)."""
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k != "meta"}
        meta = json.loads(str(npz["meta"]))
    meta.pop("history")
    return arrays, meta


@pytest.mark.parametrize("compression", [zipfile.ZIP_STORED, zipfile.ZIP_DEFLATED],
                         ids=["stored", "deflated"])
def test_cli_import_from_zip_equals_import_from_extracted_folder(tmp_path, run_less, compression):
    archive = zip_root(write_root(str(tmp_path / "src")), str(tmp_path / "dataset_poke.zip"),
                       "dataset_poke", compression)
    with zipfile.ZipFile(archive) as zf:
        zf.extractall(tmp_path / "unzipped")
    for shard in ("0/1", "1/2"):
        a = run_less("import", archive, "-o", tmp_path / "z.npz", "--shard", shard, check=True)
        b = run_less("import", tmp_path / "unzipped" / "dataset_poke", "-o", tmp_path / "f.npz", "--shard",
                     shard, check=True)
        assert a.stdout == b.stdout                        # same files, same names, same labels, same counts
        za, zmeta = _arrays_and_meta(tmp_path / "z.npz")
        fa, fmeta = _arrays_and_meta(tmp_path / "f.npz")
        assert za.keys() == fa.keys() and zmeta == fmeta
        for key in za:
            assert za[key].dtype == fa[key].dtype and za[key].shape == fa[key].shape, key
            assert za[key].tobytes() == fa[key].tobytes(), key
    rows = [json.loads(line) for line in a.stdout.decode().splitlines()]
    assert len(rows) == 2 and all(r["label"] for r in rows)


def test_hand_held_zip_finds_its_calibration_inside_the_archive(tmp_path):
    root = write_hand_held_root(str(tmp_path / "hh"))
    archive = zip_root(root, str(tmp_path / "hh.zip"), "dataset_handheld")
    from_zip = import_published(archive, ImportOptions(hand_held=True))
    from_folder = import_published(root, ImportOptions(hand_held=True))
    np.testing.assert_array_equal(from_zip.pose, from_folder.pose)
    np.testing.assert_array_equal(from_zip.labels[0].data, from_folder.labels[0].data)


def test_member_view_reads_and_seeks_like_the_member(tmp_path):
    data = bytes(range(256)) * 40
    path = tmp_path / "a.zip"
    with zipfile.ZipFile(path, "w", zipfile.ZIP_STORED) as zf:
        zf.writestr("top/pad.bin", b"x" * 1000)
        zf.writestr("top/data.bin", data)
    source = ZipSource(str(path))
    assert source.prefix == "top/" and source.files() == ["data.bin", "pad.bin"]
    with source.open("data.bin") as fh:
        assert fh.read() == data
        fh.seek(-10, os.SEEK_END)
        assert fh.read() == data[-10:] and fh.read(5) == b""
        fh.seek(300)
        assert fh.read(4) == data[300:304] and fh.tell() == 304
    source.close()
    with open(path, "rb") as raw, pytest.raises(ValueError, match="negative seek"):
        MemberView(raw, 0, 10).seek(-1)


def test_a_file_that_is_neither_folder_nor_zip_is_one_error(tmp_path):
    bad = tmp_path / "dataset.zip"
    bad.write_bytes(b"not a zip at all")
    with pytest.raises(DataError, match=r"dataset\.zip: not a directory or zip archive"):
        import_published(str(bad), ImportOptions())

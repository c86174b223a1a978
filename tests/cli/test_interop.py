"""Files other tools read: ``less info`` gives every grid in one axis order, and a prediction's NIfTI folder
holds probability maps and colour tables that 3D Slicer and ITK-SNAP load (GLB units: tests/mesh)."""

from __future__ import annotations

import json

import nibabel as nib
import numpy as np
from factories import random_scanset
from imaging_factory import save_tiny_imager

from lesscli.io.colour_tables import itksnap_table, slicer_table
from lesscli.io.labels import CLASS_NAMES
from lesscli.io.scans import save_scans
from lesscli.plots.palette import CLASS_RGBA


def test_info_gives_an_mri_scan_and_its_labels_on_one_grid_in_the_same_axis_order(run_less, tmp_path):
    made = run_less("mri-label", "--synth", "St12C13", "-o", "scan.nii.gz", "--truth-out", "truth.nii.gz",
                    "--spacing-mm", "0.8,0.6,0.5")
    assert made.returncode == 0, made.stderr.decode()
    proc = run_less("info", "scan.nii.gz", "truth.nii.gz", "--format", "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    image, labels = [json.loads(line) for line in proc.stdout.decode().splitlines()]
    assert (image["kind"], labels["kind"]) == ("image volume", "label volume")
    assert image["axes"] == labels["axes"] == "z, y, x" and image["file_axes"] == "x, y, z"
    assert image["shape"] == labels["shape"]
    assert image["spacing_mm"] == labels["spacing_mm"]
    data = nib.load(str(tmp_path / "scan.nii.gz")).shape          # the file itself is x, y, z
    assert image["shape"] == list(data[::-1])


def test_prediction_nifti_holds_probability_maps_and_colour_tables(run_less, tmp_path):
    save_tiny_imager(str(tmp_path / "im.pt"))
    save_scans(str(tmp_path / "s.npz"), random_scanset(n_scans=1, traj_per_scan=2, max_len=6, seed=1))
    proc = run_less("image", "predict", "im.pt", "s.npz", "-o", "p.npz", "--nifti", "nii", "--format",
                    "jsonl")
    assert proc.returncode == 0, proc.stderr.decode()
    files = sorted(p.name for p in (tmp_path / "nii").iterdir())
    stem = "000_St10C5_o0"                    # scan 0, its insert, orientation 0
    assert files == sorted([f"{stem}_labels.nii.gz", f"{stem}_entropy.nii.gz", "labels.ctbl",
                            "labels_itksnap.txt", *(f"{stem}_prob_{c}.nii.gz" for c in CLASS_NAMES)])
    assert json.loads(proc.stdout)["nifti_files"] == len(files)
    labels = nib.load(str(tmp_path / "nii" / f"{stem}_labels.nii.gz"))
    assert labels.header.get_intent()[0] == "label"
    probs = np.stack([np.asarray(nib.load(str(tmp_path / "nii" / f"{stem}_prob_{c}.nii.gz")).dataobj)
                      for c in CLASS_NAMES])
    assert probs.shape[1:] == labels.shape and np.allclose(probs.sum(axis=0), 1.0, atol=0.02)
    for name in CLASS_NAMES:
        np.testing.assert_array_equal(nib.load(str(tmp_path / "nii" / f"{stem}_prob_{name}.nii.gz")).affine,
                                      labels.affine)
    # argmax rule, no threshold
    np.testing.assert_array_equal(np.asarray(labels.dataobj), probs.argmax(axis=0))


def test_colour_tables_in_the_formats_slicer_and_itksnap_read():
    slicer = [line.split() for line in slicer_table(CLASS_NAMES, CLASS_RGBA).splitlines()
              if not line.startswith("#")]
    assert [row[:2] for row in slicer] == [[str(c), n] for c, n in enumerate(CLASS_NAMES)]
    assert all(len(row) == 6 and all(0 <= int(v) <= 255 for v in row[2:]) for row in slicer)
    assert slicer[0][5] == "0" and slicer[3][2:5] == [str(round(v * 255)) for v in CLASS_RGBA[3][:3]]
    snap = [line for line in itksnap_table(CLASS_NAMES, CLASS_RGBA).splitlines() if not line.startswith("#")]
    fields = [line.split(None, 7) for line in snap]
    assert ([int(f[0]) for f in fields] == [0, 1, 2, 3]
            and [f[7] for f in fields] == [f'"{n}"' for n in CLASS_NAMES])
    assert float(fields[0][4]) == 0.0 and all(float(f[4]) == 1.0 for f in fields[1:])

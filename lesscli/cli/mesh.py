"""``less mesh pred.npz|labels.nii.gz -o out.glb|.stl|.ply``: per-class surfaces in millimetres."""

from __future__ import annotations

import click

from lesscli.cli.common import check_known, format_option, output_option

CLASS_CODES = {"insert": 1, "pillar": 2, "inclusion": 3}


def _parse_classes(text: str) -> tuple[int, ...]:
    names = [t.strip() for t in text.split(",") if t.strip()]
    check_known(names, CLASS_CODES, "class", "--classes")
    codes = [CLASS_CODES[name] for name in names]
    if not codes:
        raise click.BadParameter("no class given", param_hint="--classes")
    return tuple(codes)


def load_volume(path: str, scan: int, truth: bool):
    """A LabelVolume from a label NIfTI or from scan ``scan`` of a prediction file."""
    from lesscli.errors import DataError
    from lesscli.io.labels import load_nifti_labels
    from lesscli.io.predictions import load_predictions, whole_scans

    if path.endswith((".nii", ".nii.gz")):
        return load_nifti_labels(path)
    preds = load_predictions(path)
    whole = whole_scans(preds.scans)           # a --steps file: each scan's whole sequence, not its prefixes
    if not 0 <= scan < len(whole):
        raise DataError(f"{path}: scan {scan} does not exist (the file holds {len(whole)} scans)")
    pred = preds.scans[whole[scan]]
    if truth:
        if pred.truth is None:
            raise DataError(f"{path}: scan {scan} has no truth to mesh (drop --truth)")
        return pred.truth_volume()
    return pred.label_volume()


@click.command("mesh")
@click.argument("source", type=click.Path())
@output_option(help="Output mesh: .glb (one node per class; metres, +Y up), .stl or .ply (mm, z up).")
@click.option("--scan", type=int, default=0, show_default=True, help="Scan of a prediction file to mesh.")
@click.option("--truth", is_flag=True, help="Mesh the scan's true labels instead of the prediction.")
@click.option("--classes", default="insert,pillar,inclusion", show_default=True,
              help="Comma-separated classes to mesh.")
@click.option("--smooth", type=click.IntRange(min=0), default=10, show_default=True,
              help="Taubin smoothing passes (volume-preserving).")
@click.option("--faces", type=click.IntRange(min=4), default=None,
              help="Decimate each class surface to about this many faces.")
@format_option()
def cli(source: str, output: str, scan: int, truth: bool, classes: str, smooth: int, faces: int | None,
        fmt: str | None) -> None:
    """Surfaces of each class by marching cubes, in phantom-frame millimetres.

    SOURCE is a prediction file (less.pred/1; use --scan/--truth) or a label NIfTI. Normals point
    outward; a GLB holds one named node per class, in metres with +Y up as glTF defines (viewers
    show a 60 mm phantom 0.06 m wide), STL and PLY are in mm, z up. One record per class goes to stdout.

    Example: less mesh pred.npz -o inclusion.glb --classes inclusion,pillar
    """
    from lesscli.errors import DataError
    from lesscli.io.atomic import atomic_path
    from lesscli.io.records import emit_records
    from lesscli.mesh.surfaces import export_meshes, label_meshes, mesh_format

    codes = _parse_classes(classes)
    kind = mesh_format(output)
    volume = load_volume(source, scan, truth)
    meshes = label_meshes(volume, codes, smooth_iterations=smooth, target_faces=faces)
    if not meshes:
        raise DataError(f"{source}: nothing to mesh (no {classes} voxels in the volume); no {output} written")
    with atomic_path(output, "." + kind) as tmp:
        export_meshes(meshes, tmp, kind)
    emit_records([m.record() for m in meshes], fmt)

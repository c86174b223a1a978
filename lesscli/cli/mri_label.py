"""``less mri-label SCAN -o labels.nii.gz``: segment an MRI scan of an insert into the four label classes."""

from __future__ import annotations

import click

from lesscli.cli.common import (
    LOG,
    checked_output,
    deprecated,
    format_option,
    orientation_list,
    output_option,
    renamed_option,
    seed_option,
    series_option,
)

CONTRASTS = {"silicone-darker": False, "silicone-brighter": True}


def _triple(text: str, what: str, cast=float) -> tuple:
    try:
        values = tuple(cast(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(v > 0 for v in values):
        raise click.BadParameter(f"'{text}': expected three positive numbers separated by commas",
                                 param_hint=what)
    return values


def _orientations(ctx, param, value: str) -> list[int]:
    """The shared orientation list; the old count '8' (all of them) still works for one release."""
    if value == "8":
        deprecated("--orientations 8", "--orientations 0-7")
        value = "0-7"
    return orientation_list(value, "--orientations")


def _orientation_paths(output: str, ks: list[int]) -> list[str]:
    """``labels.nii.gz`` -> ``labels_<k>.nii.gz`` per orientation k; one orientation keeps the name."""
    if len(ks) == 1:
        return [output]
    for ext in (".nii.gz", ".nii", ".npy"):
        if output.endswith(ext):
            return [f"{output[:-len(ext)]}_{k}{ext}" for k in ks]
    raise click.BadParameter(f"'{output}': expected a .nii.gz/.nii output", param_hint="-o")


def _synth(name: str, output: str, truth_out: str | None, spacing: str | None, contrast: str, noise: float,
           bias: float, seed: int) -> None:
    """Write a synthetic MRI of catalogue insert ``name`` (or the first phantom of a .toml/.json file)."""
    import numpy as np

    from lesscli.mri.synth import MRIParams, find_phantom, save_synthetic, synthesize

    phantom = find_phantom(name)
    params = MRIParams(spacing_mm=_triple(spacing, "--spacing-mm") if spacing else MRIParams.spacing_mm,
                       silicone_brighter=CONTRASTS[contrast], noise_sigma=noise, bias_amplitude=bias)
    result = synthesize(phantom, np.random.default_rng(seed), params)
    save_synthetic(result, output, truth_out)
    LOG.info("wrote %s (%s, yaw %.1f deg)", output, "x".join(map(str, result.image.shape)), result.yaw_deg)


def _label(scan_path: str, output: str, spacing: str | None, series: str | None, params, grid: str,
           grid_shape: str, grid_spacing: str, orientations: list[int], report: bool, qc: str | None,
           strict: bool, fmt: str | None) -> None:
    from lesscli.errors import DataError
    from lesscli.io.atomic import atomic_group
    from lesscli.io.records import emit_records
    from lesscli.mri import report as rep
    from lesscli.mri.scan import load_scan
    from lesscli.mri.segment import segment

    scan = load_scan(scan_path, _triple(spacing, "--spacing-mm") if spacing else None, series)
    seg = segment(scan.data, scan.spacing_mm, params, where=scan_path)
    if strict and seg.warnings:
        raise DataError(f"{scan_path}: {seg.warnings[0]} (--strict)")
    for message in seg.warnings:
        LOG.warning("%s: %s", scan_path, message)
    rows = [{"row": "contrast", "silicone_brighter": seg.silicone_brighter, **seg.levels}]
    with atomic_group():                 # the labels and the --plot figure appear together, or none of them
        rows += _write_labels(scan, seg, output, scan_path, grid, grid_shape, grid_spacing, orientations)
        if qc:
            rep.save_qc(qc, seg.corrected, seg.labels, seg.spacing_mm,
                        title=f"{scan_path}: blue insert, orange " "outline pillar, red inclusion")
    if report:
        rows += rep.shape_rows(seg.inclusion_shapes, scan.affine)
        rows += rep.base_rows(seg.base_surface, seg.spacing_mm, seg.labels.shape, scan.affine)
        rows += rep.post_rows(seg.posts, seg.spacing_mm, scan.affine)
        emit_records(rows + rep.warning_rows(seg.warnings), fmt)


def _write_labels(scan, seg, output: str, scan_path: str, grid: str, grid_shape: str, grid_spacing: str,
                  orientations: list[int]) -> list[dict]:
    """Write the labels on the scan's grid, or resampled onto the phantom grid per orientation; the
    report rows of what was written."""
    from lesscli.io.atomic import atomic_path
    from lesscli.io.labels import save_nifti
    from lesscli.mri import report as rep
    from lesscli.mri.scan import save_labels, zyx_affine

    if grid == "scan":
        save_labels(output, seg.labels, scan)
        return rep.class_rows(seg.labels, scan.affine) + rep.inclusion_rows(seg.labels, scan.affine)
    from lesscli.mri.frame import find_frame, resample, up_hint_from

    rows = []
    frame = find_frame(seg.labels, scan.affine, up_hint_from(seg.labels, seg.silicone, scan.affine),
                       scan_path)
    shape, gspacing = _triple(grid_shape, "--grid-shape", int), _triple(grid_spacing, "--grid-spacing-mm")
    for i, (k, path) in enumerate(zip(orientations, _orientation_paths(output, orientations))):
        vol = resample(seg.labels, scan.affine, frame, shape, gspacing, k, f"{scan_path}_{k}")
        with atomic_path(path, ".nii.gz" if path.endswith(".gz") else ".nii") as tmp:
            save_nifti(tmp, vol)
        if i == 0:
            aff = zyx_affine(vol.origin_mm, vol.spacing_mm)
            rows += [rep.frame_row(frame)] + rep.class_rows(vol.data, aff) + rep.inclusion_rows(vol.data, aff)
    return rows


@click.command("mri-label")
@click.argument("scan", type=click.Path(), required=False)
@output_option(help="Output labels (.nii.gz/.nii; .npy for a numpy scan). With --synth: the synthetic scan.")
@click.option("--spacing-mm", "spacing", default=None,
              help="dz,dy,dx voxel size for .npy/.npz scans (and --synth).")
@series_option()
@click.option("--pillar-max-diameter-mm", type=click.FloatRange(min=0.1), default=4.5, show_default=True,
              help="Thickest pillar; thicker silicone bodies are inclusions.")
@click.option("--pillar-diameter-mm", type=click.FloatRange(min=0.0, min_open=True), default=None,
              help="The posts' diameter as cast, where known (the mould's): each post is found, placed and "
                   "ended from the scan but drawn this wide (--report keeps its measured diameter too).")
@click.option("--skin-max-thickness-mm", type=click.FloatRange(min=0.1), default=3.0, show_default=True,
              help="Thickest silicone skin (labelled insert).")
@click.option("--smooth-mm", type=click.FloatRange(min=0.0), default=None,
              help="Gaussian denoising sigma (default 0.6 x the finest voxel size).")
@click.option("--bias-degree", type=click.IntRange(min=0, max=6), default=3, show_default=True,
              help="Polynomial degree of the log bias field corrected (0: no correction).")
@click.option("--inclusion-shape", type=click.Choice(["auto", "image", "ball"]), default="auto",
              show_default=True,
              help="Each inclusion as its fitted blurred ball (ball), as the scan's own surface (image), or "
                   "the ball where it fits the scan within its noise, else the surface (auto).")
@click.option("--grid", type=click.Choice(["scan", "phantom"]), default="scan", show_default=True,
              help="scan: labels on the input grid with its affine; phantom: the toolkit grid in the phantom "
                   "frame.")
@click.option("--grid-shape", default="26,128,128", show_default=True, help="D,H,W of the phantom grid.")
@click.option("--grid-spacing-mm", default="0.9,0.4774,0.4774", show_default=True,
              help="dz,dy,dx of the phantom grid.")
@click.option("--orientations", default="0", show_default=True, metavar="LIST", callback=_orientations,
              help="With --grid phantom: orientations k (x 45 deg), e.g. 0-7 writes OUT_0 ... OUT_7; one "
                   "orientation keeps the name OUT.")
@click.option("--report", is_flag=True,
              help="Print class volumes, inclusions, frame and warnings as records.")
@renamed_option("--qc", "--plot", "qc", type=click.Path(dir_okay=False), default=None,
                help="PNG: the three orthogonal planes through each inclusion, labels overlaid, pillar "
                     "outlined.")
@click.option("--strict", is_flag=True,
              help="Treat warnings (no inclusion, pillar not connected, ...) as errors.")
@click.option("--synth", "synth", default=None, metavar="INSERT",
              help="Instead of labelling: write a synthetic MRI of a catalogue insert (e.g. St12C13) or of "
                   "the first phantom in a .toml/.json file to -o, and its true labels to --truth-out.")
@click.option("--truth-out", type=click.Path(), default=None, callback=checked_output(),
              help="With --synth: where to write the true labels (NIfTI).")
@click.option("--contrast", type=click.Choice(sorted(CONTRASTS)), default="silicone-darker",
              show_default=True, help="With --synth: which tissue is brighter.")
@click.option("--noise", type=click.FloatRange(min=0.0), default=0.04, show_default=True,
              help="With --synth: Rician noise sigma relative to the brighter tissue.")
@click.option("--bias", type=click.FloatRange(min=0.0), default=0.25, show_default=True,
              help="With --synth: peak |log| of the multiplicative bias field.")
@seed_option()
@format_option()
def cli(scan, output, spacing, series, pillar_max_diameter_mm, pillar_diameter_mm, skin_max_thickness_mm,
        smooth_mm, bias_degree, inclusion_shape, grid, grid_shape, grid_spacing_mm, orientations, report, qc,
        strict, synth, truth_out, contrast, noise, bias, seed, fmt) -> None:
    """Label an MRI scan (NIfTI, DICOM folder, or .npy/.npz with --spacing-mm) into 0 background,
    1 insert (hydrogel and skin), 2 pillar, 3 inclusion; either tissue may be the brighter one.

    \b
    Examples:
      less mri-label --synth St12C13 -o scan.nii.gz --truth-out truth.nii.gz --seed 1
      less mri-label scan.nii.gz -o labels.nii.gz --report --plot qc.png
      less mri-label scan.nii.gz -o labels.nii.gz --pillar-diameter-mm 3 --report
      less mri-label scan.nii.gz -o grid.nii.gz --grid phantom --orientations 0-7
      less mri-label scan.npy --spacing-mm 0.5,0.5,0.5 -o labels.nii.gz
      less mri-label dicom_folder/ --series 3 -o labels.nii.gz
    """
    from lesscli.mri.segment import SegmentParams

    if synth:
        if scan:
            raise click.UsageError("--synth writes a scan; do not also give SCAN")
        _synth(synth, output, truth_out, spacing, contrast, noise, bias, seed)
        return
    if not scan:
        raise click.UsageError("missing SCAN (a NIfTI file, a DICOM folder or a .npy/.npz array)")
    if orientations != [0] and grid != "phantom":
        raise click.UsageError(f"--orientations {','.join(map(str, orientations))} needs --grid phantom")
    allowed = (".nii", ".nii.gz") + ((".npy",) if grid == "scan" else ())
    if not output.endswith(allowed):
        raise click.BadParameter(f"'{output}': expected {', '.join(allowed)}", param_hint="-o")
    if qc and not qc.endswith(".png"):
        raise click.BadParameter(f"'{qc}': expected a .png file", param_hint="--plot")
    try:
        params = SegmentParams(pillar_max_diameter_mm, skin_max_thickness_mm, smooth_mm, bias_degree,
                               inclusion_shape, pillar_diameter_mm)
    except ValueError as e:
        raise click.BadParameter(str(e), param_hint="--pillar-diameter-mm") from None
    _label(scan, output, spacing, series, params, grid, grid_shape, grid_spacing_mm, orientations, report, qc,
           strict, fmt)

"""``less import ROOT -o OUT.npz``: the published HDF5 dataset (a folder or its zip archive) -> a scan set."""

from __future__ import annotations

import click

from lesscli.cli.common import LOG, format_option, output_option, parse_shard


@click.command("import")
@click.argument("root", type=click.Path())
@output_option(lock=True)
@click.option("--every", type=click.IntRange(min=1), default=1, show_default=True,
              help="Keep every N-th step of each trajectory (50 pokes, 10 primitives; 1 keeps 100 Hz).")
@click.option("--trajectories", type=click.IntRange(min=1), default=None,
              help="Keep the first K usable trajectories per scan (100 robot, 70 hand-held in the paper).")
@click.option("--hand-held", is_flag=True, help="Use pos_estimation poses with est_to_robot_calibration.npz.")
@click.option("--calibration", type=click.Path(dir_okay=False), default=None,
              help="Calibration .npz for --hand-held (default: nearest est_to_robot_calibration.npz).")
@click.option("--labels", "labels_dir", type=click.Path(file_okay=False), default=None,
              help="Folder of 3D labels (default: ROOT/mri_images_3D).")
@click.option("--mri-scan", type=click.IntRange(min=0), default=0, show_default=True,
              help="Which MRI scan n of <insert>_<n>.npy (the lowest present if missing).")
@click.option("--top-slice", type=click.Choice(["last", "first"]), default="last", show_default=True,
              help="Which slice of the stored label volume is the top surface (z = 0).")
@click.option("--counts-per-newton", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Convert the sensor's counts to newtons with this calibration (default: keep counts, "
                   "recorded as the force unit).")
@click.option("--shard", default=None, help="Import only files i, i+n, ... of the sorted list (i/n).")
@click.option("--on-error", type=click.Choice(["fail", "skip"]), default="fail", show_default=True,
              help="A broken file stops the import, or is reported and skipped.")
@format_option()
def cli(root: str, output: str, every: int, trajectories: int | None, hand_held: bool,
        calibration: str | None, labels_dir: str | None, mri_scan: int, top_slice: str,
        counts_per_newton: float | None, shard: str | None, on_error: str, fmt: str | None) -> None:
    """Import ROOT (one HDF5 file per scan, labels in ROOT/mri_images_3D) with the published preprocessing.

    ROOT is the dataset folder or a zip archive of it (as published), read in place without
    extracting it; an archive's single top folder is its root.

    Prints one record per file (trajectories kept, dropped by reason, label, errors); with -o - the
    records go to stderr. Forces are raw sensor counts with each trajectory's first sample removed
    (``units.force = "counts"``), or newtons with --counts-per-newton (the calibration is recorded in
    ``meta.sensor.counts_per_n``). A model refuses scans whose force units differ from its training scans'.

    Example: less import dataset_poke.zip -o raw.npz --on-error skip
    """
    from lesscli.cli.common import emit_summary, progress
    from lesscli.data.published import ImportOptions, import_published
    from lesscli.io.scans import append_history, save_scans

    shard_ix = parse_shard(shard)
    opts = ImportOptions(every=every, trajectories=trajectories, hand_held=hand_held, calibration=calibration,
                         labels_dir=labels_dir, mri_scan=mri_scan, top_slice=top_slice,
                         counts_per_newton=counts_per_newton)
    rows: list[dict] = []

    def report(record: dict) -> None:
        if record["status"] == "skipped":
            LOG.warning("skipped %s", record["error"])
        rows.append(record)

    scans = import_published(root, opts, shard_ix, on_error, progress, report)
    scans.meta = append_history(scans.meta, shard=f"{shard_ix[0]}/{shard_ix[1]}")
    save_scans(output, scans)
    LOG.info("%s: %d scans, %d trajectories, %d steps", output, scans.n_scans, scans.n_traj, scans.n_steps)
    emit_summary(rows, output, fmt)

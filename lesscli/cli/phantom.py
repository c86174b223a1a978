"""``less phantom``: label volumes (NIfTI) and geometry specs for phantom sets or STL meshes."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, output_option


def _ints(text: str, what: str, count: int | None = None) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of integers", param_hint=what)
    if count is not None and len(values) != count:
        raise click.BadParameter(f"'{text}' needs {count} values", param_hint=what)
    return values


def _floats(text: str | None, what: str) -> tuple[float, float, float] | None:
    if text is None:
        return None
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of numbers", param_hint=what)
    if len(values) != 3 or min(values) <= 0:
        raise click.BadParameter(f"'{text}' needs 3 positive values dz,dy,dx", param_hint=what)
    return values  # type: ignore[return-value]


@click.command("phantom")
@click.option("--set", "set_name", default=None, metavar="NAME|FILE",
              help="Catalogue (single, multiple, large) or a .toml/.json phantom file.")
@click.option("--stl", "stl_insert", default=None, metavar="INSERT.stl", help="Voxelise a watertight insert mesh.")
@click.option("--stl-inclusion", multiple=True, metavar="MESH.stl", help="Inclusion mesh (repeatable).")
@click.option("--stl-pillar", multiple=True, metavar="MESH.stl", help="Pillar mesh (repeatable).")
@click.option("--stl-frame", type=click.Choice(["auto", "phantom"]), default="auto", show_default=True,
              help="auto: centre the insert's bounding box in x-y, top at z = 0; phantom: use file coordinates.")
@click.option("--name", default=None, help="Insert name for --stl (default: the file name).")
@output_option(help="Output folder.")
@click.option("--orientations", default="0,1,2,3,4,5,6,7", show_default=True, help="Orientations k (x 45 deg).")
@click.option("--limit", type=click.IntRange(1), default=None, help="Only the first N inserts of the set.")
@click.option("--names", default=None, help="Only these inserts (comma-separated).")
@click.option("--shape", default="26,128,128", show_default=True, help="Label grid D,H,W (z, y, x).")
@click.option("--spacing", default=None, help="Voxel size dz,dy,dx mm [default: 0.9,0.4774,0.4774, in-plane "
              "scaled with the insert width].")
@click.option("--mri", is_flag=True, help="Also write a synthetic MRI scan and its true labels per insert and "
              "orientation to OUT/mri/ (lesscli.mri.synth; a few seconds each, use --limit/--names).")
@format_option
def cli(set_name, stl_insert, stl_inclusion, stl_pillar, stl_frame, name, output, orientations, limit, names,
        shape, spacing, mri, fmt) -> None:
    """Write a NIfTI label volume and a JSON geometry spec per insert and orientation.

    Codes: 0 background, 1 insert, 2 pillar, 3 inclusion. For a set, OUT/phantoms.json lists the
    inserts at orientation 0 and can be used as phantoms.set in a scene file. One JSON record per
    volume goes to stdout.

    Examples:
      less phantom --set single --limit 2 --orientations 0,2 -o phantoms/
      less phantom --stl insert.stl --stl-inclusion ball.stl -o cad/
    """
    from lesscli.io.records import emit_records
    from lesscli.phantom.writer import write_set, write_stl

    if (set_name is None) == (stl_insert is None):
        raise click.UsageError("give exactly one of --set NAME|FILE or --stl INSERT.stl")
    if mri and set_name is None:
        raise click.UsageError("--mri needs --set NAME|FILE")
    ks = _ints(orientations, "--orientations")
    if any(not 0 <= k < 8 for k in ks):
        raise click.BadParameter("orientations must lie in 0..7", param_hint="--orientations")
    grid = _ints(shape, "--shape", 3)
    step = _floats(spacing, "--spacing")
    if stl_insert is not None:
        rows = write_stl(output, stl_insert, stl_inclusion, stl_pillar, ks, grid, step, stl_frame, name)
    else:
        rows = write_set(output, set_name, ks, grid, step, limit, names.split(",") if names else None)
    if mri:  # --mri: synthetic MRI scans of the same inserts (owned by lesscli/mri)
        from lesscli.mri.synth import write_mri_set
        from lesscli.phantom.catalogue import resolve_set
        from lesscli.phantom.writer import select

        chosen = select(resolve_set(set_name), names.split(",") if names else None, limit, set_name)
        rows += write_mri_set(output, chosen, ks)
    emit_records(rows, fmt)

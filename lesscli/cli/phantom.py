"""``less phantom``: label volumes (NIfTI) and geometry specs for phantom sets or STL meshes."""

from __future__ import annotations

import click

from lesscli.cli.common import format_option, orientations_option, output_option, renamed_option


def _ints(text: str, what: str, count: int | None = None) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise click.BadParameter(f"'{text}' is not a comma-separated list of integers", param_hint=what)
    if count is not None and len(values) != count:
        raise click.BadParameter(f"'{text}' needs {count} values", param_hint=what)
    return values


def _random_phantoms(count: int | None, seed: int | None, pairs: tuple[str, ...]):
    """The random family from --count, --seed and --random KEY=VALUE (values parse as TOML)."""
    from lesscli.io.overrides import parse_value
    from lesscli.phantom.randomised import RandomRanges, random_set

    table = {}
    for item in pairs:
        key, eq, value = item.partition("=")
        if not eq:
            raise click.BadParameter(f"'{item}' is not of the form KEY=VALUE", param_hint="--random")
        table[key.strip()] = parse_value(value, f"--random '{item}'")
    table.update({k: v for k, v in (("count", count), ("seed", seed)) if v is not None})
    return random_set(RandomRanges.from_dict(table, "--set random"))


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
              help="Catalogue (single, multiple, large), random (the randomised training family) or a "
              ".toml/.json phantom file.")
@click.option("--count", type=click.IntRange(1), default=None,
              help="--set random: number of inserts [default: 32].")
@click.option("--seed", type=click.IntRange(0), default=None, help="--set random: family seed [default: 0].")
@click.option("--random", "random_pairs", multiple=True, metavar="KEY=VALUE",
              help="--set random: a range or setting, e.g. --random diameter_mm=[8,12] (repeatable; keys as "
                   "in a scene's [phantoms.random]).")
@click.option("--stl", "stl_insert", default=None, metavar="INSERT.stl",
              help="Voxelise a watertight insert mesh.")
@click.option("--stl-inclusion", multiple=True, metavar="MESH.stl", help="Inclusion mesh (repeatable).")
@click.option("--stl-pillar", multiple=True, metavar="MESH.stl", help="Pillar mesh (repeatable).")
@click.option("--stl-frame", type=click.Choice(["auto", "phantom"]), default="auto", show_default=True,
              help="auto: centre the insert's bounding box in x-y, top at z = 0; phantom: use file "
                   "coordinates.")
@click.option("--name", default=None, help="Insert name for --stl (default: the file name).")
@output_option(help="Output folder.", folder=True)
@orientations_option()
@click.option("--limit", type=click.IntRange(1), default=None, help="Only the first N inserts of the set.")
@click.option("--names", default=None, help="Only these inserts (comma-separated).")
@renamed_option("--shape", "--grid-shape", "shape", default="26,128,128", show_default=True,
                help="Label grid D,H,W (z, y, x).")
@renamed_option("--spacing", "--spacing-mm", "spacing", default=None,
                help="Voxel size dz,dy,dx mm [default: 0.9,0.4774,0.4774, in-plane scaled with the insert "
                     "width].")
@click.option("--mri", is_flag=True,
              help="Also write a synthetic MRI scan and its true labels per insert and orientation to "
                   "OUT/mri/ (lesscli.mri.synth; a few seconds each, use --limit/--names).")
@format_option()
def cli(set_name, count, seed, random_pairs, stl_insert, stl_inclusion, stl_pillar, stl_frame, name, output,
        orientations, limit, names, shape, spacing, mri, fmt) -> None:
    """Write a NIfTI label volume and a JSON geometry spec per insert and orientation.

    Codes: 0 background, 1 insert, 2 pillar, 3 inclusion. For a set, OUT/phantoms.json lists the
    inserts at orientation 0 and can be used as phantoms.set in a scene file. One JSON record per
    volume goes to stdout. --set random draws the randomised single-inclusion family (names
    R<index>s<seed>) that training data comes from; the catalogues are for evaluation.

    \b
    Examples:
      less phantom --set single --limit 2 --orientations 0,2 -o phantoms/
      less phantom --set single --names St12C13 --orientations 0-7 --grid-shape 26,128,128 -o all/
      less phantom --set random --count 8 --seed 3 --orientations 0 -o train_phantoms/
      less phantom --stl insert.stl --stl-inclusion ball.stl -o cad/
    """
    from lesscli.io.records import emit_records
    from lesscli.phantom.writer import write_set, write_stl

    if (set_name is None) == (stl_insert is None):
        raise click.UsageError("give exactly one of --set NAME|FILE or --stl INSERT.stl")
    if mri and set_name is None:
        raise click.UsageError("--mri needs --set NAME|FILE")
    if set_name != "random" and (count is not None or seed is not None or random_pairs):
        raise click.UsageError("--count, --seed and --random go with --set random")
    ks = tuple(orientations)
    grid = _ints(shape, "--grid-shape", 3)
    step = _floats(spacing, "--spacing-mm")
    chosen = _random_phantoms(count, seed, random_pairs) if set_name == "random" else None
    if stl_insert is not None:
        rows = write_stl(output, stl_insert, stl_inclusion, stl_pillar, ks, grid, step, stl_frame, name)
    else:
        rows = write_set(output, set_name, ks, grid, step, limit, names.split(",") if names else None, chosen)
    if mri:  # --mri: synthetic MRI scans of the same inserts (owned by lesscli/mri)
        from lesscli.mri.synth import write_mri_set
        from lesscli.phantom.catalogue import resolve_set
        from lesscli.phantom.writer import select

        base = resolve_set(set_name) if chosen is None else chosen
        chosen = select(base, names.split(",") if names else None, limit, set_name)
        rows += write_mri_set(output, chosen, ks)
    emit_records(rows, fmt)

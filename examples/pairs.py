"""The scans of one set whose insert and orientation another set holds: re-palpations of chosen pairs.

The authors' data hold several scans of each insert at each orientation, so their split by scan file puts
a held-out scan's insert in training at the same orientation; the density study (``make density`` in
accuracy.mk) adds re-palpations of the training pairs only, or of every pair, to see which of the two a
model needs. This picks the first kind:

    python examples/pairs.py paper-r1.npz --of paper/train.npz -o new-r1.npz

Prints one record (scans kept, of how many, and the pairs asked for that the set lacks).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys

import numpy as np

from lesscli.errors import DataError, LessError
from lesscli.io.scans import ScanSet, append_history, load_scans, save_scans


def _pair_of_each_scan(scans: ScanSet) -> list[tuple[str, int]]:
    return list(zip(scans.scan_insert.tolist(), (int(o) for o in scans.scan_orientation.tolist())))


def pairs(scans: ScanSet) -> set[tuple[str, int]]:
    """The (insert, orientation) pairs a set holds."""
    return set(_pair_of_each_scan(scans))


def scans_of_pairs(scans: ScanSet, wanted: set[tuple[str, int]], name: str = "scan set") -> ScanSet:
    """The scans of ``scans`` (in their order) whose (insert, orientation) is in ``wanted``.

    Raises:
        DataError: no scan has one of those pairs (``name`` says which set).
    """
    keep = [i for i, pair in enumerate(_pair_of_each_scan(scans)) if pair in wanted]
    if not keep:
        raise DataError(f"{name}: no scan has an insert and orientation asked for")
    return scans.select_scans(np.asarray(keep, np.int64))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scans", help="scan set to pick from")
    ap.add_argument("--of", required=True, help="scan set whose insert-orientation pairs are kept")
    ap.add_argument("-o", "--output", required=True, help="output scan set (.npz)")
    args = ap.parse_args(argv)
    try:
        src, ref = load_scans(args.scans), load_scans(args.of)      # their errors name their file
        wanted = pairs(ref)
        out = scans_of_pairs(src, wanted, name=args.scans)
        out.meta = append_history(out.meta, argv=[], script=shlex.join(["examples/pairs.py", *argv]))
        save_scans(args.output, out)
    except LessError as err:
        print(f"pairs.py: {err}", file=sys.stderr)
        return 1
    print(json.dumps({"file": args.output, "scans": out.n_scans, "of": src.n_scans,
                      "pairs_missing": len(wanted - pairs(src))}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

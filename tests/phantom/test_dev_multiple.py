"""The development set of multiple-inclusion inserts (examples/dev_multiple.py ->
examples/scenes/dev-multiple.json)."""

import importlib.util
import math
import subprocess
import sys
from pathlib import Path

from lesscli.phantom.catalogue import GAP_BELOW_SKIN_MM, load_phantom_file, multiple

REPO = Path(__file__).resolve().parents[2]
SCRIPT = REPO / "examples" / "dev_multiple.py"
SPEC = REPO / "examples" / "scenes" / "dev-multiple.json"


def _module():
    spec = importlib.util.spec_from_file_location("dev_multiple", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_committed_file_is_what_the_script_writes():
    out = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, check=True).stdout
    assert out == SPEC.read_text()


def test_every_insert_has_several_hanging_inclusions_inside_the_filling():
    phantoms = load_phantom_file(str(SPEC))
    assert len(phantoms) == 8 and len({p.name for p in phantoms}) == 8
    for p in phantoms:
        assert len(p.inclusions) >= 2 and len(p.pillars) == len(p.inclusions)
        for s in p.inclusions:
            top_mm = s.center_mm[2] + s.radius_mm
            # the manufacturing depth
            assert math.isclose(top_mm, -(p.skin_thickness_mm + GAP_BELOW_SKIN_MM))
            # inside the octagon's flats
            assert math.hypot(*s.center_mm[:2]) + s.radius_mm < p.width_mm / 2


def test_no_insert_repeats_a_catalogue_layout():
    catalogue = {tuple(sorted(s.center_mm for s in p.inclusions)) for p in multiple()}
    for p in _module().dev_multiple():
        assert tuple(sorted(s.center_mm for s in p.inclusions)) not in catalogue

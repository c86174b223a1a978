"""The one 'did you mean' hint every error message uses."""

import pytest

from lesscli.errors import closest, did_you_mean


@pytest.mark.parametrize("name, choices, want", [
    ("simulat", ["simulate", "split", "stream"], "simulate"),
    ("motoin", {"motion": 1, "phantoms": 2}, "motion"),             # any iterable of names, dict keys too
    ("xyz", ["simulate", "split"], None),                           # nothing close: no guess
    ("", ["a"], None),
    (3, ["3", "30"], "3"),                                          # values are compared as text
])
def test_closest(name, choices, want):
    assert closest(name, choices) == want


def test_did_you_mean_wording_and_fallback():
    assert did_you_mean("pokes", ["poke", "primitive"]) == "; did you mean 'poke'?"
    assert did_you_mean("zzz", ["poke"], " (valid: poke)") == " (valid: poke)"
    assert did_you_mean("zzz", ["poke"]) == ""

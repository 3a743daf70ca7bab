"""Counts in words: one plural helper for the CLI and the reports (`sim.text.counted`), and Holm
over a family of one."""

from types import SimpleNamespace

import pytest

from analysis.reports.study_tables import holm_text
from sim.text import counted


@pytest.mark.parametrize("n, noun, words", [
    (1, "person", "1 person"), (2, "person", "2 people"), (0, "session", "0 sessions"), (1, "session", "1 session"),
    (1.0, "minute", "1 minute"), (1.5, "minute", "1.5 minutes"), (1, "registered participant", "1 registered participant"),
])
def test_counted(n, noun, words):
    assert counted(n, noun) == words


def _pair(p):
    return SimpleNamespace(p_value=p)


def test_holm_over_one_pair_is_no_correction():
    """"Holm over all 1 pairs tested"."""
    st = SimpleNamespace(holm="family", items={"q": SimpleNamespace(pairs=[_pair(0.2), _pair(float("nan"))])},
                         kinds=SimpleNamespace(family_pairs=lambda: []))
    assert holm_text(st) == "one pair tested: no Holm correction"


def test_holm_over_two_pairs():
    st = SimpleNamespace(holm="family", items={"q": SimpleNamespace(pairs=[_pair(0.2), _pair(0.3)])}, kinds=SimpleNamespace(family_pairs=lambda: []))
    assert holm_text(st) == "Holm over all 2 pairs tested"

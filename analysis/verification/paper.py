"""The seed paper's published figures the benches set beside their own: its deformation time per
frame for each model on its 2014 PC (Table 1; data/paper_deformation_time_ms.csv, the one copy)."""

from __future__ import annotations

from functools import lru_cache

from analysis.study.csvfiles import read_csv
from brainsim_assets import path as _asset

DEFORMATION_TIME = _asset("data/paper_deformation_time_ms.csv")
WORDS = {"plate_spring": "plate-spring", "fem": "FEM", "mass_spring": "mass-spring"}  # how the paper names them


@lru_cache(maxsize=1)
def deformation_ms() -> dict[str, float]:
    """{model: ms per deformation frame}, fastest first."""
    rows = read_csv(DEFORMATION_TIME, ("model", "deformation_time_ms"), ("model", "deformation_time_ms"))
    return dict(sorted(((r["model"], float(r["deformation_time_ms"])) for _, r in rows), key=lambda kv: kv[1]))


def deformation_words(unit: str = " ms") -> str:
    """The paper's times in words, fastest first: "plate-spring ... ms, FEM ... ms, mass-spring ... ms"."""
    return ", ".join(f"{WORDS.get(m, m)} {ms:.2f}{unit}" for m, ms in deformation_ms().items())

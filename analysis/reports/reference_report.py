"""The converged reference's report (`studyctl bench reference`): its forces per mesh with
Richardson's extrapolation, the meshes and the solves as Markdown, and the files it writes."""

from __future__ import annotations

import json
import math
from pathlib import Path

from analysis.reports.table import Table, markdown_grid
from sim.jsonable import jsonable


def markdown(result: dict) -> str:
    """The reference table as Markdown: the forces per pull and mesh, the meshes, and the solves."""
    m = result["meta"]
    sizes = m["sizes_mm"]
    forces = Table(columns=["pull", "d (mm)", *(f"F @ {s:g} mm (N)" for s in sizes), "order", "status", "extrapolated (N)", "band (N)",
                            "band %", "< JND (rel)", "< 0.05 N", "energy outside data", "max abs(J - 1)"],
                   rows=[[s["pull"], f"{s['displacement_mm']:g}", *(f"{f:.4f}" for f in s["forces_n"]), _fmt(s["order"], ".2f"), s["status"],
                          _fmt(s["force_ext_n"], ".4f"), f"{s['band_n'][0]:.4f}..{s['band_n'][1]:.4f}", f"{s['gci']:.1%}",
                          "yes" if s["within_jnd_rel"] else "no", "yes" if s["within_jnd_abs"] else "no",
                          _fmt(s["support_share_outside"], ".0%"), _fmt(s["max_abs_j_minus_1"], ".3f")] for s in result["samples"]])
    meshes = Table(columns=["hemisphere", "target edge (mm)", "nodes", "tets", "h (mm)", "P2 dofs (free)", "volume error", "mesh s"],
                   rows=[[g["hemisphere"], f"{g['target_edge_mm']:g}", g["nodes"], g["tets"], f"{g['h_mm']:.2f}", g["free_dofs"],
                          f"{g['volume_error']:+.2%}", f"{g['mesh_s']:.1f}{' (cached)' if g['cached'] else ''}"] for g in result["meshes"]])
    lines = [f"P2, {m['formulation']}, on fTetWild meshes (target edges {', '.join(f'{s:g}' for s in sizes)} mm); "
             f"GCI factor of safety {m['gci_fs']:g}; GCI half-band median {m['gci_median']:.1%}, largest {m['gci_max']:.1%}"
             + (" (quick)" if m["quick"] else "") + ".", "", *markdown_grid(forces), "", *markdown_grid(meshes)]
    if any(s for p in result["pulls"] for s in p["solves"]):
        solves = Table(columns=["pull", "mesh (mm)", "converged", "load steps", "Newton iterations", "factorisations", "smallest det F", "s", "stored"],
                       rows=[[p["pull"], f"{s['size_mm']:g}", "yes" if s["converged"] else "no: " + s.get("reason", ""), s.get("load_steps", "-"),
                              s.get("iterations", "-"), s.get("factorisations", "-"), f"{s.get('min_jacobian', math.nan):.2f}",
                              f"{s.get('seconds', math.nan):.0f}", "yes" if s.get("cached") else "no"]
                             for p in result["pulls"] for s in p["solves"]])
        lines += ["", *markdown_grid(solves)]
    return "\n".join(lines) + "\n"


def _fmt(x, spec: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else format(x, spec)


def write_outputs(result: dict, out_dir) -> list[Path]:
    """reference.json and reference.md."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = [out / "reference.json", out / "reference.md"]
    files[0].write_text(json.dumps(jsonable(result), indent=2))
    files[1].write_text(markdown(result))
    return files

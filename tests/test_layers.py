"""The layers run one way (issue 28): the simulator (sim) imports neither the study library
(studyctl) nor the analyses (analysis), so it runs, ships and is tested without them; the study
library imports no analysis outside its CLI."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _imports(path: Path) -> set[str]:
    """Top-level packages a module imports, anywhere in it (inside functions too)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module.split(".")[0])
    return out


def test_sim_imports_neither_the_study_library_nor_the_analyses():
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & {"analysis", "studyctl"}) for p in sorted((ROOT / "sim").rglob("*.py"))}
    assert {k: v for k, v in offenders.items() if v} == {}


def test_the_study_library_imports_no_analysis_outside_its_cli():
    """Sessions, storage and synthetic participants run without the statistics; the CLI, which
    offers both, is the one place that joins them (analysis may read studies: studyctl)."""
    files = [p for p in sorted((ROOT / "studyctl").rglob("*.py")) if "cli" not in p.relative_to(ROOT / "studyctl").parts[:-1]]
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & {"analysis"}) for p in files}
    assert len(files) > 15 and {k: v for k, v in offenders.items() if v} == {}


def _module_graph() -> tuple[list[str], dict[str, set[str]]]:
    """The project's modules and who imports whom, function-level imports included (`from a
    import b` counts a.b where that is a module)."""
    files = {}
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = p.relative_to(ROOT).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p

    def resolve(name: str) -> str | None:
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {m: set() for m in files}
    for mod, path in files.items():
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                targets = {resolve(f"{node.module}.{a.name}") or resolve(node.module) for a in node.names}
            elif isinstance(node, ast.Import):
                targets = {resolve(a.name) for a in node.names}
            else:
                continue
            edges[mod] |= {t for t in targets if t and t != mod}
    return list(files), edges


def test_no_import_cycles_between_the_projects_modules():
    """Strongly connected components of the import graph (scipy), function-level imports
    included: an import inside a function hides a cycle from Python, not from the design. The
    CLI's commands may import each other (they are one program's entry points)."""
    import numpy as np
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    mods, edges = _module_graph()
    index = {m: i for i, m in enumerate(mods)}
    pairs = [(index[a], index[b]) for a, bs in edges.items() for b in bs]
    graph = csr_matrix((np.ones(len(pairs)), tuple(zip(*pairs))), shape=(len(mods), len(mods)))
    _, label = connected_components(graph, directed=True, connection="strong")
    groups: dict[int, list[str]] = {}
    for m, lab in zip(mods, label):
        groups.setdefault(int(lab), []).append(m)
    cycles = {tuple(sorted(g)) for g in groups.values() if len(g) > 1 and not all(m.startswith("studyctl.cli") for m in g)}
    assert len(mods) > 120 and edges["studyctl.protocol"] >= {"studyctl.fields", "studyctl.text"}
    assert cycles == set()


def test_no_private_name_is_imported_from_another_package():
    """A leading underscore is a module's own: another package uses its public API."""
    offenders = []
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
                if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                    top = node.module.split(".")[0]
                    if top in ("sim", "studyctl", "analysis") and top != pkg:
                        offenders += [f"{p.relative_to(ROOT)}:{node.lineno} {node.module}.{a.name}" for a in node.names if a.name.startswith("_")]
    assert offenders == []


def test_no_module_is_over_600_lines():
    """A module past 600 lines holds more than one concept (issue 45): split it by concept."""
    sizes = {str(p.relative_to(ROOT)): p.read_text().count("\n") for pkg in ("sim", "studyctl", "analysis") for p in (ROOT / pkg).rglob("*.py")}
    assert len(sizes) > 120 and {k: v for k, v in sizes.items() if v > 600} == {}


SQL = re.compile(r"^\s*(select\s.+\sfrom\s|insert\s+(or\s+\w+\s+)?into\s|update\s+\w+\s+set\s|delete\s+from\s|create\s+(table|index)\s)",
                 re.I | re.S)


def test_only_the_store_layer_writes_sql():
    """The study library and the reports call studyctl/store/'s functions (issue 45): a string
    that starts an SQL statement anywhere else is a query that has lost its home."""
    found = []
    for pkg in ("sim", "studyctl", "analysis"):
        for p in sorted((ROOT / pkg).rglob("*.py")):
            if p.is_relative_to(ROOT / "studyctl" / "store"):
                continue
            for node in ast.walk(ast.parse(p.read_text(), filename=str(p))):
                if isinstance(node, ast.Constant) and isinstance(node.value, str) and SQL.match(node.value):
                    found.append(f"{p.relative_to(ROOT)}:{node.lineno}")
    in_store = sum(1 for p in (ROOT / "studyctl" / "store").rglob("*.py")
                   for node in ast.walk(ast.parse(p.read_text())) if isinstance(node, ast.Constant) and isinstance(node.value, str)
                   and SQL.match(node.value))
    assert found == [] and in_store > 100  # the check sees the store's own statements

"""The layers run one way: the simulator (sim) imports neither the study library (studyctl) nor
the analyses (analysis), so it runs, ships and is tested without them (issue 28)."""

import ast
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

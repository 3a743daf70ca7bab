"""The layers run one way (issue 28): the simulator (sim) imports neither the study library
(studyctl) nor the analyses (analysis), so it runs, ships and is tested without them; the study
library imports no analysis outside its CLI."""

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


def test_the_study_library_imports_no_analysis_outside_its_cli():
    """Sessions, storage and synthetic participants run without the statistics; the CLI, which
    offers both, is the one place that joins them (analysis may read studies: studyctl)."""
    files = [p for p in sorted((ROOT / "studyctl").rglob("*.py")) if "cli" not in p.relative_to(ROOT / "studyctl").parts[:-1]]
    offenders = {str(p.relative_to(ROOT)): sorted(_imports(p) & {"analysis"}) for p in files}
    assert len(files) > 15 and {k: v for k, v in offenders.items() if v} == {}

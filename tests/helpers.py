"""What the tests share: protocols, scenes and data built for them, the CLI in this process, and a person at a pseudo-terminal."""

import hashlib
import json
import math
import os
import re
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from analysis.study.questions import Question
from sim.geometry.mesh import SurfaceMesh
from sim.geometry.patch import SUBDIVISIONS, _patch_quadrature
from sim.hyperelastic import Hyperelastic
from studyctl.cli import cli
from studyctl.synthetic.observer import DEFAULT, logit
from tests.conftest import ROOT

PROTOCOL = ROOT / "protocols" / "brain_pull_2015.toml"
JND = ROOT / "protocols/stiffness_jnd.toml"  # the shipped discrimination protocol
BAD = "tests.plugins.bad_models"  # the test plugins' module (tests/plugins), for "package.module:Class"
# names no participant-facing text may contain: a model's or a parameter's
MODEL_WORDS = re.compile(r"plate.?spring|mass.?spring|\bfem\b|finite|element|corotational|neo.?hookean|young|poisson", re.I)


def _fast(protocol: Path, tmp_path: Path, trials: int, training: float) -> str:
    """The text of shipped `protocol` on a coarse (8 mm) brain with short trials: its scene
    rewritten into `tmp_path` (the FEM on linear tetrahedra: the study machinery under test does
    not need P2's accuracy, and P2 costs 3-4 s more to assemble in every process that builds
    it; test_fem_model, test_accuracy and test_stability test the shipped P2), `trials` of 1 s
    per condition, `training` minutes."""
    scene = (ROOT / "protocols/scenes/brain_pull.toml").read_text()
    scene = scene.replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/').replace('"../materials/', f'"{ROOT}/protocols/materials/')
    scene = scene.replace("\norder = 2 ", "\norder = 1 ", 1).replace('kind = "offscreen"', 'kind = "none"')
    (tmp_path / "scene.toml").write_text(scene)
    text = protocol.read_text().replace('scene = "scenes/brain_pull.toml"', f'scene = "{tmp_path / "scene.toml"}"')
    text = text.replace("trials_per_condition = 3", f"trials_per_condition = {trials}").replace("trial_seconds = 3.0", "trial_seconds = 1.0")
    return text.replace("training_minutes = 5.0", f"training_minutes = {training}")


def fast_protocol(tmp_path: Path, conditions=("plate_spring", "fem", "mass_spring"), trials=2, training=0.0) -> Path:
    """The shipped protocol on a coarse brain, short trials: quick synthetic sessions (`_fast`)."""
    text = _fast(PROTOCOL, tmp_path, trials, training)
    text = text.replace('conditions = ["fem", "mass_spring", "plate_spring"]', f"conditions = {json.dumps(list(conditions))}")
    path = tmp_path / "protocol.toml"
    path.write_text(text)
    return path


def variants_protocol(tmp_path: Path) -> Path:
    """The shipped ratings example (protocols/plate_spring_variants.toml: Likert items, the SUS
    after each condition, a choice at the end) on the same coarse scene, one short trial per
    condition (`_fast`)."""
    path = tmp_path / "variants.toml"
    path.write_text(_fast(ROOT / "protocols/plate_spring_variants.toml", tmp_path, trials=1, training=0.0))
    return path


def studyctl(*args, env=None):
    return CliRunner().invoke(cli, [str(a) for a in args], env=env, catch_exceptions=False)


def tree_state(d: Path) -> dict:
    """Every file and folder under `d` (side files and lock folders included), files with their
    SHA-256: what a refused or reading command must leave as it was."""
    return {str(p.relative_to(d)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "folder" for p in sorted(d.rglob("*"))}


def query(db, sql, params=()):
    """Rows of `sql` on `db`, read with plain sqlite3 (not the store under test)."""
    con = sqlite3.connect(db)
    try:
        return con.execute(sql, params).fetchall()
    finally:
        con.close()


def count_rows(db, table: str = "answers") -> int:
    """Rows in `table` of a database another process may be writing (0 before it exists)."""
    try:
        return sqlite3.connect(db, timeout=10).execute(f"select count(*) from {table}").fetchone()[0]
    except sqlite3.OperationalError:
        return 0


def pty_run(argv, on_output=None, timeout=60.0) -> tuple[str, int]:
    """Run `studyctl ARGV` on a real pseudo-terminal; after each chunk of output,
    `on_output(fd, out)` (out: a bytearray of all the terminal showed so far) may type, or append
    a marker to `out`. Killed at `timeout`. Returns (all the terminal showed, exit status)."""
    import pty
    import select

    pid, fd = pty.fork()
    if pid == 0:  # the child: a real session on a terminal
        signal.signal(signal.SIGINT, signal.SIG_DFL)  # pytest-xdist's workers ignore SIGINT, and an ignored signal stays so across exec
        os.execv(sys.executable, [sys.executable, "-m", "studyctl.cli", *map(str, argv)])
    out = bytearray()
    deadline = time.time() + timeout
    while time.time() < deadline:
        if not select.select([fd], [], [], 0.5)[0]:
            continue
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
        if on_output is not None:
            on_output(fd, out)
    else:
        os.kill(pid, 9)
    _, status = os.waitpid(pid, 0)
    return out.decode(errors="replace"), os.waitstatus_to_exitcode(status)


def pty_session(argv, answer=None, timeout=60.0, on_output=None, replies: dict[str, list[str]] | None = None) -> str:
    """Run `studyctl ARGV` on a real pseudo-terminal (`pty_run`) and answer its prompts: each
    time the output ends with a "[y/n]" prompt, type `answer()` and Enter; or, with `replies`,
    each time it ends with one of their prompt tails (e.g. "[1-7]"), type that tail's next reply
    (each must be used up; asking once more than given fails). `on_output(fd, text so far)` may
    type more. Returns all the terminal showed."""
    left = {tail: list(r) for tail, r in (replies or {"[y/n]": []}).items()}

    def respond(fd, out: bytearray) -> None:
        if on_output is not None:
            on_output(fd, out)
        tail = out.decode(errors="replace").rstrip()
        for prompt, todo in left.items():
            if tail.endswith(prompt):
                if replies is None:
                    reply = answer()
                else:
                    assert todo, f"asked once more than expected: {prompt}\n{tail[-500:]}"
                    reply = todo.pop(0)
                os.write(fd, (reply + "\n").encode())
                out += b"<sent>"
                break

    text, _ = pty_run(argv, respond, timeout)
    if replies is not None:
        assert not any(left.values()), (left, text[-2000:])
    return text


def localise(text: str) -> str:
    """Make the shipped scene's relative paths absolute, so a copy works from tmp_path."""
    return text.replace('"../../data/', f'"{ROOT}/data/').replace('"../models/', f'"{ROOT}/protocols/models/').replace('"../materials/', f'"{ROOT}/protocols/materials/')


def box(nx, ny, nz, h, origin=(0.0, 0.0, 0.0)):
    """A box of nx x ny x nz cubes of side h from `origin`, in tetrahedra (sim.geometry.volume.grid_tets)."""
    import numpy as np


    return grid_tets(np.ones((nx, ny, nz), bool), np.asarray(origin, float), h)


def participant_protocol(tmp_path, trial_seconds=3.0, rest=0.5, **kw):
    """`fast_protocol` with `trial_seconds`-long trials and `rest` seconds of rest between them."""
    p = fast_protocol(tmp_path, **kw)
    text = p.read_text().replace("trial_seconds = 1.0", f"trial_seconds = {trial_seconds}").replace("rest_seconds = 5.0", f"rest_seconds = {rest}")
    p.write_text(text)
    return p


FIELDS = '''
[fields.experience]
kind = "choice"
values = ["student", "resident", "neurosurgeon"]
required = true

[fields.years]
kind = "integer"
min = 0
max = 40

[fields.hours_per_week]
kind = "number"

[fields.note]
kind = "text"
'''


def field_protocol(tmp_path: Path, fields: str = FIELDS, groups: str | None = "experience", conditions=("plate_spring", "fem", "mass_spring"),
                   trials=2) -> Path:
    """`fast_protocol` with participant `fields` (FIELDS: one of each kind) and design.groups `groups`."""
    path = fast_protocol(tmp_path, conditions=conditions, trials=trials)
    text = path.read_text()
    if groups is not None:
        text = text.replace("[design]\n", f"[design]\ngroups = {json.dumps(groups)}\n", 1)
    path.write_text(text + fields)
    return path


KINDS_CONDITIONS = """
[conditions.paper]
model = "plate_spring"
variant = "paper"

[conditions.located]
model = "plate_spring"
variant = "located"
"""

QUESTIONS = """
[[questions]]
id = "natural"
text = "Is interaction real and natural?"
kind = "likert"
points = 7
anchors = ["Not at all", "Completely"]

[[questions]]
id = "realtime"
text = "Is the interaction real-time?"
kind = "likert"
points = 7
anchors = ["Not at all", "Completely"]

[[questions]]
id = "stiffness"
text = "How stiff did the tissue feel?"
kind = "vas"
anchors = ["Very soft", "Very stiff"]

[[questions]]
id = "stable"
text = "Is the system stable?"

[[questions]]
id = "smooth"
text = "Was that pull smooth?"
kind = "likert"
points = 5
anchors = ["Not at all", "Very"]
when = "trial"

[[questions]]
id = "comment"
text = "Anything else?"
kind = "text"
when = "end"

[[questions]]
id = "most_like_tissue"
text = "Which condition felt most like real brain tissue?"
kind = "choice"
when = "end"

[[instruments]]
name = "sus"

[[instruments]]
name = "nasa_tlx"
"""


def kinds_protocol(tmp_path, questions=QUESTIONS, conditions=("paper", "located"), trials=2):
    """`fast_protocol` on two plate-spring variants (KINDS_CONDITIONS) asking `questions` (QUESTIONS: every kind, two instruments)."""
    path = fast_protocol(tmp_path, conditions=conditions, trials=trials)
    text = path.read_text()
    text = text[: text.index("[[questions]]")].replace("[inclusion]", KINDS_CONDITIONS + "\n[inclusion]") + questions
    path.write_text(text)
    return path


def jnd_protocol(tmp_path: Path, conditions=("plate_spring",), trials=12, method="quest+", extra="") -> Path:
    """The shipped discrimination protocol on the quick scene (linear FEM tetrahedra, no
    pictures), 1 s intervals, `trials` per condition."""
    fast_protocol(tmp_path)  # writes tmp_path / "scene.toml"
    text = JND.read_text().replace('scene = "scenes/brain_pull.toml"', f'scene = "{tmp_path / "scene.toml"}"')
    text = text.replace('conditions = ["fem", "mass_spring_3it", "plate_spring"]', f"conditions = {json.dumps(list(conditions))}")
    if "mass_spring_3it" not in conditions:  # the shipped mass-spring condition's table goes with it
        head, rest = text.split("[conditions.mass_spring_3it]")
        text = head + rest[rest.index("[[tasks]]"):]
    text = text.replace("trials = 40", f"trials = {trials}").replace("training_minutes = 2.0", "training_minutes = 0.0")
    text = text.replace('method = "quest+"', f'method = "{method}"' + extra).replace("trial_seconds = 3.0", "trial_seconds = 1.0")
    path = tmp_path / "jnd.toml"
    path.write_text(text)
    return path


def plugin_scene(tmp_path, target: str) -> Path:
    """The fast test scene running `target` ("package.module:Class"), one hand."""
    fast_protocol(tmp_path)
    text = (tmp_path / "scene.toml").read_text()
    text = text.replace("[models.plate_spring]", f'[models."{target}"]\nstiffness = 300.0\n\n[models.plate_spring]', 1)
    path = tmp_path / "plugin_scene.toml"
    path.write_text(text)
    return path


def synthetic_content(db):
    """A synthetic study database's answers, trials, orders and observer features, sorted: equal for equal studies."""
    con = sqlite3.connect(db)
    answers = con.execute("select code, model, item, answer, session_id, source from answers order by code, model, item").fetchall()
    trials = con.execute("select session_id, model, trial, round(max_force_n, 9) from trials order by session_id, model, trial").fetchall()
    orders = con.execute("select code, conditions from schedule order by code").fetchall()
    feats = con.execute("select code, model, feature, value from observer_features order by code, model, feature").fetchall()
    con.close()
    return answers, trials, orders, feats


def synthetic_summary(ratio, flops=1e4, ripple=0.0, events=0):
    """A trial's summary for the synthetic observer: forces rendered at `ratio` times the truth."""
    import numpy as np

    from studyctl.synthetic.observer import TrialSummary

    truth = np.linspace(0.05, 1.0, 40)
    return TrialSummary(rendered=ratio * truth, truth=truth, ripple=ripple, events=events, frame_flops=flops)


def _copy_sources(dest: Path) -> Path:
    """The files git would put in a clone (tracked, plus new ones not ignored): the wheel is
    built from these, in a copy, so the checkout gets no build/ or egg-info."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT, check=True,
                           capture_output=True).stdout.decode().split("\0")
    for rel in filter(None, files):
        src = ROOT / rel
        if src.is_file():
            (dest / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / rel)
    return dest


def build_wheel(tmp: Path) -> Path:
    """Build brainsim's wheel from a copy of the sources (`_copy_sources`) into tmp/dist; its path."""
    src = _copy_sources(tmp / "src")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)], check=True,
                   capture_output=True)
    (wheel,) = (tmp / "dist").glob("brainsim_study-*.whl")
    return wheel


def latex_problems(tex: str, folder: Path) -> list[str]:
    """Compile the LaTeX document `tex` with pdflatex in `folder`: its errors, overfull boxes
    over 1 pt and floats too large for the page, as lines of its log ([] when it fits)."""
    (folder / "doc.tex").write_text(tex)
    run = subprocess.run(["pdflatex", "-interaction=nonstopmode", "-halt-on-error", "doc.tex"], cwd=folder,
                         capture_output=True, text=True, timeout=120)
    log = (folder / "doc.log").read_text(errors="replace")
    problems = [ln for ln in log.splitlines() if ln.startswith("!") or "Float too large" in ln]
    for m in re.finditer(r"Overfull \\[hv]box \(([\d.]+)pt too (?:wide|high)\)[^\n]*", log):
        if float(m.group(1)) > 1.0:
            problems.append(m.group(0))
    if run.returncode != 0 or not (folder / "doc.pdf").exists():
        problems.append(f"pdflatex exit {run.returncode}")
    return problems


TEXT_NUMBER = re.compile(r"(?<![\w.])(-?\d*\.?\d+)(%?)(?![\w.]*\d)")


def _leaves(obj, numbers: list, strings: list) -> None:
    if isinstance(obj, dict):
        for v in obj.values():
            _leaves(v, numbers, strings)
    elif isinstance(obj, list):
        for v in obj:
            _leaves(v, numbers, strings)
    elif isinstance(obj, bool) or obj is None:
        return
    elif isinstance(obj, (int, float)):
        numbers.append(float(obj))
    elif isinstance(obj, str):
        strings.append(obj)


def unsupported_numbers(text: str, doc: dict) -> list[str]:
    """The numbers of `text` that no value of `doc` gives at the printed precision (as printed,
    or as a percentage), once the strings `doc` holds (question texts, names, versions, formulas)
    are taken out of the text. 'p < .001' is checked against the p-values below .001."""
    numbers, strings = [], []
    _leaves(doc, numbers, strings)
    for s in sorted(set(strings), key=len, reverse=True):
        if len(s) >= 3 and s in text:
            text = text.replace(s, " ")
    missing = []
    if "p < .001" in text:
        if not any(0 <= x < 0.0005 for x in numbers):
            missing.append("p < .001")
        text = text.replace("p < .001", " ")
    for m in TEXT_NUMBER.finditer(text):
        token, percent = m.group(1), m.group(2)
        value = float(token)
        decimals = len(token.split(".")[1]) if "." in token else 0
        scale = 100.0 if percent else 1.0
        if not any(round(x * scale, decimals) == round(value, decimals) for x in numbers):
            missing.append(m.group(0))
    return missing


# -- closed forms and small geometry the tests build on (no library code calls them) ----------------

def simple_shear(law: Hyperelastic, gamma: float) -> np.ndarray:
    """The first Piola-Kirchhoff stress (3, 3) in simple shear F = I + gamma e1 (x) e2 (J = 1,
    so no volumetric part): the Cauchy stress sum_i s_i n_i (x) n_i in the principal frame of
    b = F F^T, s_i = sum_p (2 mu_p/alpha_p)(l_i^alpha_p - mean_j l_j^alpha_p), times F^-T."""
    F = np.eye(3)
    F[0, 1] = gamma
    c, n = np.linalg.eigh(F @ F.T)
    lam = np.sqrt(c)
    s = np.zeros(3)
    for m, a in zip(law.mu, law.alpha):
        pw = lam**a
        s += 2.0 * m / a * (pw - pw.mean())
    sigma = (n * s) @ n.T
    return sigma @ np.linalg.inv(F).T


def icosphere(radius: float = 0.05, subdivisions: int = 2, center=(0.0, 0.0, 0.0)) -> SurfaceMesh:
    """A procedural sphere for unit tests (12 * 4**s ... vertices)."""
    t = (1.0 + 5**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
    )
    verts = list(v / np.linalg.norm(v, axis=1, keepdims=True))

    def mid(a: int, b: int, cache: dict) -> int:
        key = (min(a, b), max(a, b))
        if key not in cache:
            m = verts[a] + verts[b]
            verts.append(m / np.linalg.norm(m))
            cache[key] = len(verts) - 1
        return cache[key]

    for _ in range(subdivisions):
        cache: dict[tuple[int, int], int] = {}
        nf = []
        for a, b, c in f:
            ab, bc, ca = mid(a, b, cache), mid(b, c, cache), mid(c, a, cache)
            nf += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        f = np.array(nf)
    return SurfaceMesh(np.array(verts) * radius + np.asarray(center), f.astype(np.int32))


_CORNERS = np.array([[(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)])
_KUHN = np.array([[0, 1, 3, 7], [0, 3, 2, 7], [0, 2, 6, 7], [0, 6, 4, 7], [0, 4, 5, 7], [0, 5, 1, 7]])


def grid_tets(inside: np.ndarray, origin: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and Kuhn tetrahedra of the kept cells of a grid. `inside`: (nx, ny, nz) bool."""
    cells = np.argwhere(inside)  # (c, 3) cell indices
    if len(cells) == 0:
        return np.zeros((0, 3)), np.zeros((0, 4), dtype=np.int64)
    corners = cells[:, None, :] + _CORNERS[None, :, :]  # (c, 8, 3) grid-node indices
    dims = np.array(inside.shape) + 1
    flat = np.ravel_multi_index(corners.reshape(-1, 3).T, dims).reshape(-1, 8)
    used, inverse = np.unique(flat, return_inverse=True)
    local = inverse.reshape(-1, 8)
    ijk = np.stack(np.unravel_index(used, dims), axis=1)
    nodes = origin + ijk * h
    tets = local[:, _KUHN].reshape(-1, 4)
    return nodes, tets


def patch_vertex_weights(mesh, vertex: int, radius: float, subdivisions: int = SUBDIVISIONS) -> tuple[np.ndarray, np.ndarray]:
    """The same mean on the surface vertices: (vertex ids (k,), weights (k,) summing to 1), so
    that sum_i w_i u_i is the mean of the piecewise-linear surface displacement over the patch.
    Vertices just outside the radius whose triangles reach into it get a share."""
    sel, lam, parent, _, w = _patch_quadrature(mesh, vertex, radius, subdivisions)
    if len(w) == 0:
        return np.array([vertex], dtype=np.int64), np.ones(1)
    ids = sel[parent].ravel()
    vals = (lam * w[:, None]).ravel()
    uniq, inv = np.unique(ids, return_inverse=True)
    acc = np.zeros(len(uniq))
    np.add.at(acc, inv, vals)
    return uniq, acc / acc.sum()


def p_yes(item: str, feats: dict, traits, params=None) -> float:
    """A yes/no question's P(yes) (`item`: its id): the logistic function of the observer's `logit`."""
    return 1.0 / (1.0 + math.exp(-logit(Question(item, item), feats, traits, DEFAULT if params is None else params)))


def lockstep_trace(scene, enabled: bool, monkeypatch, duration: float = 3.0):
    """(`scene` run in lockstep for `duration` s, the ticks the compiled kernel ran), with the
    compiled ticks on or off (sim/servo/lockstep.py)."""
    import sim.servo.lockstep as lockstep
    from sim.run import run_scene

    counted = {"compiled": 0}
    kernel = lockstep._ticks

    def counting(*args):
        done = kernel(*args)
        counted["compiled"] += done
        return done

    monkeypatch.setattr(lockstep, "ENABLED", enabled)
    monkeypatch.setattr(lockstep, "_ticks", counting)
    return run_scene(scene, duration=duration, time_scale=0), counted["compiled"]

"""`studyctl calibrate material` on odd data (docs/material.md, "Odd data"): exact repeats
counted once with a warning, a data set given twice refused, rows that are not one curve (kPa
and Pa mixed, scatter) refused, a region of zero stresses and a fit that explains nothing refused,
too many points refused before any fit, progress per law, and the provenance of a written file
that is the command as run."""

import hashlib
import json
import shlex

import numpy as np

from analysis.verification.material_fit import (
    DATA_FILE,
    MAX_POINTS,
    SCATTER_MAX,
    SHEAR_FILE,
    UNIT_JUMP,
    curve_scatter,
    fit_material,
    read_curve,
)
from sim.material import load_material
from tests.helpers import studyctl


def _cortex_rows() -> list[str]:
    return [line for line in DATA_FILE.read_text().splitlines()[1:] if line.startswith("cortex,")]


def _data(tmp_path, rows, name="d.csv"):
    path = tmp_path / name
    path.write_text("region,stretch,nominal_stress_kpa\n" + "\n".join(rows) + "\n")
    return path


def _fit(*args):
    res = studyctl("calibrate", "material", "--law", "neo-hookean", *args)
    return res


def test_rows_repeated_exactly_are_counted_once_with_a_warning(tmp_path):
    rows = _cortex_rows()
    once, twice = _data(tmp_path, rows, "once.csv"), _data(tmp_path, rows + rows[:10], "twice.csv")
    res = _fit("--data", twice, "--json")
    assert res.exit_code == 0, res.output
    warning = res.stderr.strip().splitlines()[-1]  # after the law's stage line
    assert warning == (f"warning: {twice}: 10 rows of region cortex repeated an earlier row exactly (same strain and stress) "
                       f"and counted once; {len(rows)} points fitted")
    merged = json.loads(res.stdout)
    assert merged["files"][0]["points"] == len(rows)
    assert merged["files"][0]["duplicates_merged"] == 10
    alone = json.loads(_fit("--data", once, "--json").stdout)
    assert merged["laws"][0]["ci95"] == alone["laws"][0]["ci95"]  # the intervals of the data without the copies


def test_the_same_strain_with_another_stress_is_a_point_of_its_own(tmp_path):
    rows = _cortex_rows()
    region, stretch, stress = rows[5].split(",")
    res = _fit("--data", _data(tmp_path, rows + [f"{region},{stretch},{float(stress) * 1.01:.4f}"]), "--json")
    assert res.exit_code == 0, res.output
    assert json.loads(res.stdout)["files"][0]["points"] == len(rows) + 1


def test_a_region_of_zero_stresses_is_refused_and_nothing_is_written(tmp_path):
    rows = [",".join(r.split(",")[:2] + ["0"]) for r in _cortex_rows()]
    data = _data(tmp_path, rows)
    before = hashlib.sha256(data.read_bytes()).hexdigest()
    res = _fit("--data", data, "--out", tmp_path / "m.toml")
    assert res.exit_code == 1
    assert res.output == f"Error: {data}: region 'cortex': every nominal_stress_kpa is 0; there is nothing to fit\n"
    assert not (tmp_path / "m.toml").exists()
    assert hashlib.sha256(data.read_bytes()).hexdigest() == before


def test_a_fit_that_explains_nothing_is_refused(tmp_path):
    """Stresses of the wrong sign (pulling in compression, pushing in tension): no law with
    positive moduli follows them; its best is no better than the data's mean."""
    rows = [f"{r.split(',')[0]},{r.split(',')[1]},{-float(r.split(',')[2]):.4f}" for r in _cortex_rows()]
    data = _data(tmp_path, rows)
    res = _fit("--data", data, "--out", tmp_path / "m.toml")
    assert res.exit_code == 1
    *stages, line = res.output.strip().splitlines()
    assert stages == ["calibrate material: fitting neo-hookean (law 1 of 1)"]
    assert line.startswith(f"Error: {data}: region 'cortex': no law explains these data (the chosen neo-hookean: R^2 "), line
    assert line.endswith(", no better than the data's mean); nothing fitted")
    assert "inf%" not in res.output
    assert not (tmp_path / "m.toml").exists()


def test_too_many_points_are_refused_before_any_fit(tmp_path):
    n = MAX_POINTS + 1
    rows = [f"cortex,{0.9 + 0.2 * k / n:.8f},{(0.2 * k / n - 0.1) * 10:.8f}" for k in range(n)]
    data = _data(tmp_path, rows)
    res = _fit("--data", data)
    assert res.exit_code == 1
    assert res.output == (f"Error: {data}: region 'cortex' has {n} points; allowed: at most {MAX_POINTS} a file "
                          "(bin or thin the curve, e.g. a mean stress per strain step)\n")


def test_progress_is_reported_once_the_data_are_read_and_after_each_law():
    seen = []
    fit_material(DATA_FILE, "cortex", ("neo-hookean", "mooney-rivlin"), progress=lambda k, n: seen.append((k, n)))
    assert seen == [(0, 2), (1, 2), (2, 2)]


def test_a_log_gets_a_stage_line_on_stderr_as_each_law_starts():
    """stderr here is no terminal (a log, a pipe): no bar there, a line per law instead."""
    res = studyctl("calibrate", "material", "--law", "neo-hookean", "--law", "ogden", "--json")
    assert res.exit_code == 0, res.output
    assert res.stderr.splitlines() == ["calibrate material: fitting neo-hookean (law 1 of 2)",
                                       "calibrate material: fitting ogden (law 2 of 2)"]


def test_the_stage_lines_leave_the_json_document_on_stdout_whole():
    res = studyctl("calibrate", "material", "--law", "neo-hookean", "--json")
    assert res.exit_code == 0, res.output
    assert [f["law"] for f in json.loads(res.stdout)["laws"]] == ["neo-hookean"]


def test_the_largest_region_allowed_is_well_above_the_shipped_data():
    """The cap bounds a fit's time; the shipped curves (a few dozen points a region) fit under it."""
    for path in (DATA_FILE, SHEAR_FILE):
        regions = [line.split(",")[0] for line in path.read_text().splitlines()[1:] if line]
        assert max(regions.count(r) for r in set(regions)) <= MAX_POINTS, path


def test_the_written_provenance_is_the_command_as_run(tmp_path):
    out = tmp_path / "m.toml"
    args = ["calibrate", "material", "--data", str(DATA_FILE), "--region", "cortex", "--law", "ogden", "--bulk-ratio", "40",
            "--out", str(out)]
    res = studyctl(*args)
    assert res.exit_code == 0, res.output
    command = "studyctl " + " ".join(shlex.quote(a) for a in args).replace("--bulk-ratio 40", "--bulk-ratio 40.0")
    assert f"# Written by `{command}`." in out.read_text().splitlines()
    assert load_material(out)[1]["command"] == command


# --- a data set given twice, rows that are not one curve -------------------------------------

def _alternating(rows, factor=1000.0):
    """Every other row's stress in Pa under the kPa column."""
    return [f"{r.split(',')[0]},{r.split(',')[1]},{float(r.split(',')[2]) * (factor if k % 2 else 1.0):.4f}" for k, r in enumerate(rows)]


def _refused(tmp_path, *files):
    """`calibrate material --data F ... --out m.toml` refused: exit 1, no traceback, nothing
    written, the data files unchanged; its last line."""
    out = tmp_path / "m.toml"
    before = [hashlib.sha256(f.read_bytes()).hexdigest() for f in files]
    res = _fit(*[a for f in files for a in ("--data", f)], "--out", out)
    assert res.exit_code == 1, res.output
    assert "Traceback" not in res.output
    assert not out.exists()
    assert [hashlib.sha256(f.read_bytes()).hexdigest() for f in files] == before
    return res.output.strip().splitlines()[-1]


def test_the_same_file_twice_is_refused(tmp_path):
    data = _data(tmp_path, _cortex_rows())
    line = _refused(tmp_path, data, data)
    assert line == f"Error: {data}: the same rows as {data} (33 of 33); give each data set once"


def test_the_same_file_through_a_link_is_refused(tmp_path):
    data = _data(tmp_path, _cortex_rows())
    link = tmp_path / "link.csv"
    link.symlink_to(data)
    line = _refused(tmp_path, data, link)
    assert line == f"Error: {link}: the same rows as {data} (33 of 33); give each data set once"


def test_two_files_of_the_same_rows_are_refused(tmp_path):
    a, b = _data(tmp_path, _cortex_rows(), "A.csv"), _data(tmp_path, list(reversed(_cortex_rows())), "B.csv")
    line = _refused(tmp_path, a, b)
    assert line == f"Error: {b}: the same rows as {a} (33 of 33); give each data set once"


def test_two_loading_modes_together_are_still_fitted():
    assert fit_material([DATA_FILE, SHEAR_FILE], "cortex", ("neo-hookean",))["fit"] == "neo-hookean"


def test_rows_alternating_kpa_and_pa_are_refused_naming_the_rows(tmp_path):
    data = _data(tmp_path, _alternating(_cortex_rows()))
    line = _refused(tmp_path, data)
    assert line.startswith(f"Error: {data}: region 'cortex': nominal_stress_kpa jumps "), line
    assert "x between neighbouring rows and back (line 2: -1.1484 at stretch 0.9; line 3: -1000.5 at 0.9062)" in line
    assert line.endswith(": kPa and Pa mixed? give every row in kPa; nothing fitted")


def test_one_row_in_pa_among_rows_in_kpa_is_refused(tmp_path):
    rows = _cortex_rows()
    rows[20] = _alternating(rows[19:21])[1]
    line = _refused(tmp_path, _data(tmp_path, rows))
    assert "kPa and Pa mixed?" in line


def test_rows_scattered_far_beyond_a_mean_curve_are_refused(tmp_path):
    """Every other row 1.6x, the rest 0.4x: no 100x jump, but no curve either."""
    rows = [f"{r.split(',')[0]},{r.split(',')[1]},{float(r.split(',')[2]) * (1.6 if k % 2 else 0.4):.4f}"
            for k, r in enumerate(_cortex_rows())]
    data = _data(tmp_path, rows)
    line = _refused(tmp_path, data)
    assert line.startswith(f"Error: {data}: region 'cortex': the rows scatter about their neighbours by "), line
    assert line.endswith(f"of the stresses' RMS; allowed: at most {SCATTER_MAX:.0%} (a measured mean curve is smooth: the shipped "
                         "curves scatter by under 3%); mixed units, or two data sets in one? nothing fitted")


def test_the_shipped_curves_scatter_far_below_the_limit():
    for path in (DATA_FILE, SHEAR_FILE):
        for region in ("cortex", "basal_ganglia", "corona_radiata", "corpus_callosum"):
            c = read_curve(path, region)
            assert curve_scatter(c.x, c.stress) < SCATTER_MAX / 5, (path.name, region)


def test_the_shipped_curves_thinned_to_eleven_points_still_pass():
    """Sparser points: their neighbours' line bends with the curve, and the measure grows."""
    for path in (DATA_FILE, SHEAR_FILE):
        c = read_curve(path, "corpus_callosum")
        assert curve_scatter(c.x[::3], c.stress[::3]) < SCATTER_MAX / 2, path.name


def test_rows_alternating_kpa_and_pa_scatter_far_above_the_limit(tmp_path):
    c = read_curve(DATA_FILE, "cortex")
    mixed = c.stress * np.where(np.arange(len(c.x)) % 2 == 1, 1000.0, 1.0)
    assert curve_scatter(c.x, mixed) > 2 * SCATTER_MAX


def test_no_shipped_row_jumps_near_the_unit_limit():
    for path in (DATA_FILE, SHEAR_FILE):
        for region in ("cortex", "basal_ganglia", "corona_radiata", "corpus_callosum"):
            y = read_curve(path, region).stress
            same = (y[:-1] * y[1:]) > 0
            a, b = np.abs(y[:-1][same]), np.abs(y[1:][same])
            assert (np.maximum(a, b) / np.minimum(a, b)).max() < UNIT_JUMP / 10, (path.name, region)

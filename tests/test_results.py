"""A study's results are typed to the leaves: complete when built and never changed after (frozen
records, read-only containers), and turned into JSON dicts (`as_dict`) only where JSON is written."""

import ast
import json
from collections.abc import Mapping
from dataclasses import FrozenInstanceError, fields
from types import MappingProxyType

import pytest

from analysis.statistics.result_records import (
    ChoicePair,
    ChoiceTest,
    DifferencePair,
    Friedman,
    GeeFit,
    McNemarPair,
    MixedModelFit,
    ModelTest,
    OddsRatioPair,
    OrdinalGeeFit,
    RankPair,
    Record,
)
from analysis.statistics.study_stats import study_stats
from sim.jsonable import jsonable
from studyctl.cli.common import read_snapshot
from tests.conftest import ROOT

# the modules that write JSON, the only ones that call as_dict: the CLI's --json paths, and the
# records' own conversion (a record's as_dict gives its inner records' as theirs)
# where JSON is written: the commands, report table1's JSON (analysis/reports/study_report.py), the records
# themselves, and sim/jsonable.py (what every JSON writer calls)
AS_DICT_CALLERS = {"studyctl/cli/reports.py", "studyctl/cli/plan.py", "studyctl/cli/model.py", "analysis/reports/study_report.py", "analysis/statistics/result_records.py", "analysis/statistics/facts.py",
                   "analysis/statistics/study_results.py", "sim/jsonable.py"}


def _walk(obj, path: str):
    """(path, value) of a result and of everything inside it."""
    yield path, obj
    if isinstance(obj, Record):
        for f in fields(obj):
            yield from _walk(getattr(obj, f.name), f"{path}.{f.name}")
    elif isinstance(obj, Mapping):
        for k, v in obj.items():
            yield from _walk(v, f"{path}[{k!r}]")
    elif isinstance(obj, (list, tuple, set)):
        for i, v in enumerate(obj):
            yield from _walk(v, f"{path}[{i}]")


@pytest.fixture(scope="module")
def results(small_study, variants_study):
    """The results of a study of yes/no questions and of one of ratings, a score and a choice."""
    return [study_stats(read_snapshot(small_study)), study_stats(read_snapshot(variants_study))]


def test_no_container_in_a_study_result_can_be_changed(results):
    for st in results:
        mutable = [path for path, v in _walk(st, "st") if isinstance(v, (dict, list, set))]
        assert mutable == []


def test_every_kind_of_leaf_is_a_typed_record(results):
    kinds = {type(v) for st in results for _, v in _walk(st, "st")}
    leaves = {McNemarPair, RankPair, DifferencePair, ChoicePair, OddsRatioPair, Friedman, ModelTest, ChoiceTest, MixedModelFit, GeeFit,
              OrdinalGeeFit}
    assert leaves - kinds == set()


def test_every_record_refuses_a_new_value(results):
    records = [(path, v) for st in results for path, v in _walk(st, "st") if isinstance(v, Record)]
    for _path, v in records:
        with pytest.raises(FrozenInstanceError):
            setattr(v, fields(v)[-1].name, None)


def test_a_result_mapping_refuses_a_key(results):
    st = results[1]
    rating = next(iter(st.kinds.ratings.values()))
    for mapping in (st.items, st.kinds.ratings, rating.conditions, st.kinds.scores, st.kinds.choices):
        assert isinstance(mapping, MappingProxyType)
        with pytest.raises(TypeError):
            mapping["new"] = 1


def _records() -> list[type]:
    """Every result record class (the subclasses of Record, all the way down)."""
    import analysis.statistics.study_results  # noqa: F401  (every result module imported: their classes registered)

    out, todo = [], [Record]
    while todo:
        cls = todo.pop()
        out.append(cls)
        todo += cls.__subclasses__()
    return out


def test_no_result_record_has_an_untyped_field():
    # a keyed container holds records or plain values; nothing holds a bare mapping or a list of them
    names = {c.__name__ for c in _records()} | {"str", "int", "float", "bool"}
    bad = []
    for cls in _records():
        for f in fields(cls):
            text = str(f.type).removesuffix(" | None")
            if "Mapping" not in text and "dict" not in text:
                continue
            inner = text.removeprefix("Mapping[str, ").removesuffix("]") if text.startswith("Mapping[str, ") else None
            if inner is None or not {t.strip() for t in inner.split("|")} <= names:
                bad.append(f"{cls.__name__}.{f.name}: {text}")
    assert bad == []


def test_every_leaf_of_a_result_is_a_record_or_a_plain_value(results):
    plain = (str, int, float, bool, type(None))
    for st in results:
        odd = [path for path, v in _walk(st, "st") if not isinstance(v, (Record, MappingProxyType, tuple, *plain))
               and type(v).__module__ != "numpy"]
        assert odd == []


def test_a_results_pairs_are_a_tuple(results):
    rating = next(iter(results[1].kinds.ratings.values()))
    assert isinstance(rating.pairs, tuple)


def test_holm_is_in_every_family_pair_when_built(results):
    st = results[1]
    pairs = [p for part in (st.kinds.ratings, st.kinds.scores, st.kinds.choices) for v in part.values() for p in v.pairs]
    missing = [p for p in pairs if p.p_holm is None or p.p_holm_family is None or p.p_holm_question is None]
    assert pairs
    assert missing == []


def test_a_record_gives_back_its_tests_dict_keys_in_order():
    raw = {"a": "x", "b": "y", "difference": 1.0, "se": 0.1, "ci_low": 0.8, "ci_high": 1.2, "p_value": 0.2, "estimable": True,
           "test": "t contrast"}
    assert DifferencePair.of(raw).as_dict() == raw
    assert list(DifferencePair.of(raw).as_dict()) == list(raw)


def test_a_record_leaves_out_the_keys_its_test_did_not_give():
    raw = {"a": "x", "b": "y", "difference": 1.0, "se": 0.1, "ci_low": 0.8, "ci_high": 1.2, "p_value": 0.2, "estimable": True}
    assert "reason" not in DifferencePair.of(raw).as_dict()


def test_a_key_a_record_does_not_have_is_refused():
    with pytest.raises(TypeError):
        McNemarPair.of({"a": "x", "b": "y", "test": "exact McNemar", "n01": 1, "n10": 2, "p_value": 0.5, "p_holm": 0.5,
                        "odds_ratio": 1.0, "surprise": 1})


def test_a_records_inner_list_is_a_tuple_and_comes_back_a_list():
    fit = GeeFit.of({"formula": "f", "n_participants": 1, "n_answers": 2, "correlation": "c", "covariance": "v", "converged": False,
                     "estimable": False, "problems": ["why"], "pairs": []})
    assert fit.problems == ("why",)
    assert fit.as_dict()["problems"] == ["why"]


def test_the_json_of_a_result_is_plain_dicts_and_lists(results):
    d = results[0].as_dict()
    kinds = {type(v) for _, v in _walk(d, "d")}
    assert kinds & {MappingProxyType, tuple} == set()
    assert json.loads(json.dumps(jsonable(d)))["holm"] == "family"


def _as_dict_callers() -> set[str]:
    out = set()
    for top in ("analysis", "sim", "studyctl"):
        for path in sorted((ROOT / top).rglob("*.py")):
            tree = ast.parse(path.read_text(encoding="utf-8"))
            if any(isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr == "as_dict" for n in ast.walk(tree)):
                out.add(path.relative_to(ROOT).as_posix())
    return out


def test_as_dict_is_called_only_where_json_is_written():
    assert _as_dict_callers() - AS_DICT_CALLERS == set()


def test_a_file_valued_option_is_named_by_its_file():
    """A condition's option that names a file ({file, sha256} in its stored configuration) is
    written as the file's name in the conditions line and the methods (their JSON keeps the whole
    configuration under facts.conditions)."""
    from analysis.reports.study_tables import condition_text
    from analysis.statistics.facts import ConditionRun
    from analysis.statistics.methods import _model

    cfg = {"model": "plate_spring", "variant": "located", "options": {"field": {"file": "field.npz", "sha256": "ab" * 32}, "params": None},
           "material": {"young": 3000.0, "poisson": 0.45}}
    run = ConditionRun(condition="loc", model="plate_spring", config_json=json.dumps(cfg), config_sha256="0" * 64, sessions=1, source=None)
    assert "(field field.npz, variant located" in condition_text(run)
    assert _model(run.config)["options"] == {"field": "field.npz", "variant": "located"}
    assert run.as_dict()["config"] == cfg

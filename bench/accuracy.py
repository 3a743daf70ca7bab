"""The quick accuracy bench (studyctl bench accuracy --quick) in one process: per model row,
force error on the held-out pulls against the reference and frame time as a ratio to the seed
paper's, at each of the bench's speeds. `python -m bench accuracy [--json]` (keys
`accuracy.<model>.<setting>.<speed>.<calibration>.*`)."""

from __future__ import annotations

from analysis.reports.accuracy_tables import within_text
from analysis.reports.formatting import shown
from analysis.verification.accuracy import quick_config, run_accuracy
from analysis.verification.paper import deformation_ms
from bench.common import main_with_json


def measure() -> dict:
    out = run_accuracy(quick_config(), jobs=1)  # one process: timings without a neighbour on the other core
    ref = out["meta"]["reference"]
    print(f"reference {ref['setting']} (converged: {ref['converged']}); the linear models' E = {out['meta']['young_pa'] / 1e3:.3g} kPa; "
          "quick bench: timings, and a smoke run of the rest (it decides nothing)")
    for r in out["rows"]:
        paper = deformation_ms()[r["model"]]
        print(f"  {r['model'] + '/' + r['setting'] + '/' + r['speed'] + '/' + r['calibration']:54s} force error {shown(r['force_error'], '6.1%')} "
              f"(max {shown(r['force_error_max'], '6.1%')}), within JND {within_text(r)}; "
              f"tick {r['tick_us']:.2f} us; frame p50 {r['frame_ms']:.3g} ms, "
              f"p99 {r['frame_ms_p99']:.3g} ms = {r['frame_ms'] / paper:.3g} x paper's {paper} ms")
    return out


def flat(out: dict) -> dict:
    keys = {}
    for r in out["rows"]:
        name = f"accuracy.{r['model']}.{r['setting']}.{r['speed']}.{r['calibration']}"
        for k in ("force_error", "force_error_max", "within_jnd", "tick_us", "frame_ms", "frame_ms_p99"):
            keys[f"{name}.{k}"] = r[k]
        keys[f"{name}.frame_ms.ratio_to_paper"] = r["frame_ms"] / deformation_ms()[r["model"]]
    return keys


def main() -> None:
    main_with_json(measure, flat)


if __name__ == "__main__":
    main()

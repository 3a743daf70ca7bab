"""The observer's deterministic latency against the measured one, per study model.

A synthetic participant perceives deformation latency as the model's counted work per frame
turned into time on the reference machine (`studyctl.synthetic.observer.frame_ms`: overhead + flops /
rate), so answers do not depend on the machine's load. This bench runs each condition of the
shipped protocol for one 3 s trial in lockstep and prints the measured deformation time per
frame (median, p95) next to the predicted one and their ratio: how far the cost model is from
this machine. `--json` prints the same with stable keys.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

PROTOCOL = Path(__file__).resolve().parents[1] / "protocols" / "brain_pull_2015.toml"


def main() -> None:
    from sim.run import run_scene
    from studyctl.conditions import condition_scene
    from studyctl.protocol import load_protocol
    from studyctl.synthetic.observer import DEFAULT, frame_ms

    protocol = load_protocol(PROTOCOL)
    out = {}
    for model in protocol.conditions:
        scene = condition_scene(protocol, model, "simulated")
        run_scene(scene, duration=0.5, time_scale=0)  # warm-up: first-frame allocations
        r = run_scene(scene, duration=protocol.trial_seconds, time_scale=0)
        measured = r.deformation_s * 1e3
        flops = float(np.nanmean(r.frame_flops))
        predicted = frame_ms(flops)
        out[model] = {"frame_flops": flops, "predicted_ms": predicted, "measured_ms_p50": float(np.median(measured)),
                      "measured_ms_p95": float(np.percentile(measured, 95)), "ratio_predicted_to_measured": predicted / float(np.median(measured))}
    meta = {"frame_overhead_ms": DEFAULT.frame_overhead_ms, "flops_per_ms": DEFAULT.flops_per_ms}
    if "--json" in sys.argv:
        print(json.dumps({"observer": {f"{m}.{k}": v for m, d in out.items() for k, v in d.items()} | meta}, indent=2))
        return
    print(f"reference machine: {DEFAULT.frame_overhead_ms:g} ms + flops / {DEFAULT.flops_per_ms:.3g} per ms")
    for m, d in out.items():
        print(f"{m:<13} {d['frame_flops']:10.3g} flops/frame  predicted {d['predicted_ms']:8.3f} ms  measured p50 {d['measured_ms_p50']:8.3f} ms "
              f"p95 {d['measured_ms_p95']:8.3f} ms  predicted/measured {d['ratio_predicted_to_measured']:.2f}")


if __name__ == "__main__":
    main()

"""Run the benchmarks: `python -m bench` (all) or `python -m bench plate_spring servo 10`
(a number is an argument for the benchmark before it: seconds, for servo; `--json` makes
each benchmark print only JSON with stable keys, one object per benchmark). `fem_static` (the
tissue's law solved statically on the accuracy bench's pulls, about 15 min) and
`fem_quasi_newton` (a real-time method tried for that law, about 5 min) run only when named."""

import importlib
import sys

ALL = ["plate_spring", "fem", "mass_spring", "render", "servo", "startup", "synthetic", "accuracy", "observer"]

if __name__ == "__main__":
    names = [a for a in sys.argv[1:] if not a.replace(".", "", 1).isdigit() and not a.startswith("--")]
    for name in names or ALL:
        if "--json" not in sys.argv:  # --json: nothing but the benchmark's JSON on stdout
            print(f"== bench.{name}", flush=True)
        importlib.import_module(f"bench.{name}").main()

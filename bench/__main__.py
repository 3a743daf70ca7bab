"""Run the benchmarks: `python -m bench` (all) or `python -m bench plate_spring render`."""

import importlib
import sys

ALL = ["plate_spring", "fem", "mass_spring", "render", "servo"]

if __name__ == "__main__":
    for name in sys.argv[1:] or ALL:
        print(f"== bench.{name}")
        importlib.import_module(f"bench.{name}").main()

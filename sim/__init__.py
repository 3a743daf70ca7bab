"""The simulator, the bottom layer: scenes, tissue models, devices, the servo, the view. It imports
neither the analyses nor the study library, so it runs, ships and is tested alone.

Here: scenes and their files (`scene`, `tomlfile`, `tomltable`, `material`, `files`, `text`), the
laws a tick evaluates (`laws`, `hyperelastic`), runs (`run`, `run_plots`), the pulls
every model is measured on (`pulls`), parallel sweeps (`sweep`). Sub-packages: `geometry`,
`models`, `devices`, `servo`, `view`.
"""

from brainsim_assets import version as _version

__version__ = _version()

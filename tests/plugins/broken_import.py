"""A plugin whose import fails (tests/test_plugins.py)."""

import brainsim_no_such_dependency  # noqa: F401

from sim.models.api import TissueModel


class Model(TissueModel):
    pass

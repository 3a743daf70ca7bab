"""Construct validity: performance metrics from the recorded traces (`metrics`, on the signal
processing of `kinematics`) and whether experts and novices differ, learn, and can be told apart
(`groups`).

Imports: numpy, scipy, pandas, statsmodels, scikit-learn, `sim`, `analysis.study` and
`analysis.statistics`; never `analysis.reports`.
"""

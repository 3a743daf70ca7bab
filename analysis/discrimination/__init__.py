"""Stiffness discrimination: each participant's psychometric fit (`psychometric`), the JND report
(`jnd`), the Weber fractions' group test (`weber_groups`) and the pooled fit (`pooled`).

Imports: numpy, scipy, statsmodels, the study snapshot and statistics in `analysis`, and `sim`.
"""

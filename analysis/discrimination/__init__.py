"""Stiffness discrimination: each participant's psychometric fit (`psychometric`), the task's
results (`jnd`: Weber fractions per participant and condition, their summaries and group test;
its tables and pages are `analysis.reports.jnd_report`'s), the Weber fractions' group test
(`weber_groups`) and the pooled fit (`pooled`).

Imports: numpy, scipy, statsmodels, the study snapshot and statistics in `analysis`, and `sim`.
"""

"""The statistics of a study and their typed results: the tests (`stats`, `scales`), when a
statistic may be given (`withhold`), the yes/no Table 1 (`table1`), every other kind of answer
(`kinds`), the model faults (`faults`), the methods as data (`methods`), everything together
(`study_stats`), and the frozen records they return (`result_records`, `kind_results`,
`study_results`, `facts`).

Imports: numpy, scipy, pandas, statsmodels, `sim`, and `analysis.study`; never `analysis.reports`.
"""

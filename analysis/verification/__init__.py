"""The verification of tissue models against the tissue: the truth they are judged by and how far
each model is from it.

- `tissue_pulls`: the tissue's finite-strain pulls; `reference`: the converged reference over
  three meshes; `convergence`: Richardson extrapolation and GCI; `truth`, `truth_table`,
  `truth_band`: the tables the synthetic observer reads and their validity band;
- `accuracy`: the fair bench of every model class; `stability`: the stability sweep;
  `material_fit`: a law fitted to measured tissue; `field_fit`: the located plate-spring's field;
  `model_check`: a model against the contract and the truth; `paper`: the seed paper's figures;
  `regions`: the truth's grey and white laws.

They return data; their tables, pages and files are in `analysis/reports/`.

Imports: numpy, scipy, `sim` (scenes, models, pulls), the Wilson interval of
`analysis.statistics.stats` and the CSV reader of `analysis.study.csvfiles`; never a study's
statistics or results, `analysis.reports` or studyctl.
"""

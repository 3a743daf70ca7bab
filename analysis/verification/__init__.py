"""The verification of tissue models against the tissue: the truth they are judged by and how far
each model is from it.

- `tissue_pulls`: the tissue's finite-strain pulls; `reference`: the converged reference over
  three meshes; `convergence`: Richardson extrapolation and GCI; `truth`, `truth_table`,
  `truth_band`: the tables the synthetic observer reads and their validity band;
- `accuracy`, `accuracy_tables`: the fair bench of every model class; `stability`: the stability
  sweep; `material_fit`: a law fitted to measured tissue; `field_fit`: the located plate-spring's
  field; `model_check`: a model against the contract and the truth.

Imports: numpy, scipy, and `sim` (scenes, models, pulls); never the study statistics or studyctl.
"""

"""The study as the analyses read it: the snapshot of a study database (`study_snapshot`), the
question and answer vocabulary (`questions`), the standard instruments and their scoring
(`instruments`), CSV files as people make them (`csvfiles`) and a trial's trace file (`trace_files`).

Imports: numpy, pandas and `sim`; nothing else of `analysis`.
"""

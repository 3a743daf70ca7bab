"""The study as the analyses read it: the snapshot of a study database (`study_snapshot`), the
protocol as they read it (`protocol_view`, a structural type of studyctl's protocol), who is a
complete participant (`completeness`, the one rule every count uses), the question and answer
vocabulary (`questions`, with the question kinds), the kinds of participant field (`fields`), the
standard instruments and their scoring (`instruments`), CSV files as people make them
(`csvfiles`) and a trial's trace file (`trace_files`).

Imports: numpy, pandas, `sim` and `analysis.errors`; nothing else of `analysis`.
"""

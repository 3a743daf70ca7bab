"""The analyses, the middle layer: the statistics of studies and the verification of models. They
import `sim` and never `studyctl`; a study reaches them as a snapshot
(`analysis.study.study_snapshot.Study`).

Sub-packages by concept: `study` (the study's vocabulary and files both layers read),
`statistics` (the tests of a study and their typed results), `validity` (construct validity from
the performance metrics), `discrimination` (stiffness discrimination: psychometric fits, Weber
fractions), `verification` (the models against the tissue's truth) and `reports` (every table,
sentence, page and figure). Here: `errors`, the input errors they share.
"""

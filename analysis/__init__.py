"""The analyses, the middle layer: the statistics of studies and the verification of models. They
import `sim` and never `studyctl`; a study reaches them as a snapshot (`study_snapshot.Study`).

Here: the study's vocabulary both layers read (`questions`, `instruments`, `errors`, `csvfiles`,
`trace_files`), the statistics (`stats`, `scales`, `kinds`, `withhold`, `table1`, `study_stats`,
`validity`, `metrics`, `kinematics`) and their typed results. Sub-packages: `discrimination`,
`reports`, `verification`.
"""

"""Every table, sentence, page and figure made from a study or a bench: Table 1 in each format
(`study_report`, `study_tables`), every other kind of answer (`kind_tables`), the faults
(`fault_tables`), the LaTeX and HTML documents (`report`), the methods and results text
(`paper_text`), the discrimination task (`jnd_report`), construct validity (`validity_report`), the
benches and the model check (`accuracy_tables`, `stability_report`, `reference_report`,
`model_check_report`), figures (`plots`, `figure_size`), the one table of every report and its
renderers (`table`), and the formats shared by every report (`formatting`, `latex`).

Imports: matplotlib (only when a figure is drawn), the rest of `analysis`, and `sim`; nothing
else of `analysis` imports it.
"""

"""Reports made from a study: the LaTeX and HTML documents (`report`), the methods and results
text (`paper_text`, `methods`), construct validity (`validity_report`), figures (`plots`,
`figure_size`), the one table of every report and its renderers (`table`), and the formats shared by
every report (`formatting`, `latex`).

Imports: matplotlib (only when a figure is drawn), the statistics in `analysis`, and `sim`.
"""

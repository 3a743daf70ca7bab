"""Statistics, Table 1, accuracy and stability reports, plots."""

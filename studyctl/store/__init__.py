"""The store layer: the only code that writes SQL. `database` opens, migrates and guards the
SQLite file (`Store`); the other modules hold the statements of one concept each, as functions
of an open `Store` or of a transaction's connection, which the study library and the reports
call. Imports: sqlite-utils, pandas, `analysis` (the errors, the snapshot it reads into) and
nothing else of studyctl but its own modules and the completeness count."""

from studyctl.store.database import (
    EXPORT_TABLES,
    IDENTIFYING_TABLES,
    SCHEMA_VERSION,
    Store,
    dumps,
    init_study,
    inspect,
    migrate_study,
    now,
    sha256_file,
)

__all__ = ["EXPORT_TABLES", "IDENTIFYING_TABLES", "SCHEMA_VERSION", "Store", "dumps", "init_study", "inspect", "migrate_study", "now", "sha256_file"]

"""Study management library and the `studyctl` CLI."""

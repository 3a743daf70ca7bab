"""The study library and the `studyctl` CLI, the top layer: protocols, participants, scheduling,
the store, sessions, synthetic participants. It imports `analysis` and `sim`; nothing imports it.

Sub-packages: `store` (the only SQL), `session`, `synthetic`, `cli` (parses options, calls one
library function, prints).
"""

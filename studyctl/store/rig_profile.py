"""The study's rig profile (`rig_profile`): each configuration's measured frame times, kept with
the study so its synthetic participants perceive the rig's latency."""

from __future__ import annotations

from studyctl.store.database import Store


def keep_rows(conn, rows: list[dict], profile: dict, source: str, verb: str = "replace") -> None:
    """Profile rows into `rig_profile` inside the caller's transaction (`verb`: replace an older row, or ignore)."""
    conn.executemany(f"insert or {verb} into rig_profile (key, condition, model, frame_ms_p50, frame_ms_p95, frames, machine, "
                     "measured_at, source) values (?, ?, ?, ?, ?, ?, ?, ?, ?)",
                     [(r["key"], r.get("condition"), r.get("model"), float(r["frame_ms_p50"]), float(r["frame_ms_p95"]), r.get("frames"),
                       profile.get("machine"), profile.get("measured_at"), source) for r in rows])


def profile_rows(store: Store) -> list[dict]:
    """key, frame_ms_p50, source and machine of every stored configuration."""
    return store.rows("select key, frame_ms_p50, source, machine from rig_profile")


def has_profile(store: Store) -> bool:
    """Whether the study keeps a rig profile of its own."""
    return bool(store.rows("select 1 from rig_profile limit 1"))


def session_count(store: Store) -> int:
    """How many sessions the study holds (any state)."""
    return store.rows("select count(*) as n from sessions")[0]["n"]

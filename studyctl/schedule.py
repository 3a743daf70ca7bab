"""Counterbalancing (Williams design), slot allocation on one rig, iCalendar export; a
participant's counterbalanced order and a study's schedule, stored (`assign_order`, `schedule_study`)."""

from __future__ import annotations

import datetime as dt
import json
from pathlib import Path
from zoneinfo import ZoneInfo

from analysis.errors import InputError
from analysis.study.csvfiles import read_csv
from studyctl.outputs import refuse_existing, write_file
from studyctl.store import Store, roster
from studyctl.store.participant_fields import group_of


def williams(n: int) -> list[list[int]]:
    """Williams (1949) orders of n conditions: each condition precedes every other equally
    often. n rows for even n; for odd n the square and its mirror (2n rows)."""
    first = [0]
    lo, hi = 1, n - 1
    for k in range(1, n):  # 0, 1, n-1, 2, n-2, ...
        if k % 2 == 1:
            first.append(lo)
            lo += 1
        else:
            first.append(hi)
            hi -= 1
    rows = [[(c + r) % n for c in first] for r in range(n)]
    if n % 2 == 1:
        rows += [list(reversed(r)) for r in rows]
    return rows


def next_order(conditions: tuple[str, ...], completed_orders: list[int], assigned: list[int]) -> int:
    """The Williams row with the fewest completed sessions (then fewest assigned): a withdrawal
    does not unbalance the design, its row is simply given again."""
    rows = williams(len(conditions))
    def key(i):
        return (completed_orders.count(i), assigned.count(i), i)
    return min(range(len(rows)), key=key)


def _parse_hours(hours: str) -> tuple[dt.time, dt.time]:
    try:
        a, b = hours.split("-")
        start, end = dt.time.fromisoformat(a), dt.time.fromisoformat(b)
    except ValueError:
        raise InputError(f"--hours: {hours!r} is not HH:MM-HH:MM") from None
    if start >= end:
        raise InputError(f"--hours: {hours!r} ends before it starts")
    return start, end


def read_availability(path: str | Path) -> dict[str, list[tuple[dt.datetime, dt.datetime]]]:
    """CSV with columns code, date, start, end (local times); all rows valid or none used."""
    path = Path(path)
    out: dict[str, list] = {}
    for line, row in read_csv(path, ("code", "date", "start", "end"), ("code", "date", "start", "end")):
        try:
            day = dt.date.fromisoformat(row["date"])
            a = dt.datetime.combine(day, dt.time.fromisoformat(row["start"]))
            b = dt.datetime.combine(day, dt.time.fromisoformat(row["end"]))
        except (ValueError, TypeError):
            raise InputError(f"{path}: line {line}: date must be YYYY-MM-DD and start/end HH:MM") from None
        if a >= b:
            raise InputError(f"{path}: line {line}: end is not after start")
        out.setdefault(row["code"], []).append((a, b))
    return out


def allocate(codes: list[str], start: dt.date, end: dt.date, hours: str = "09:00-17:00", minutes: int = 45,
             availability: dict | None = None, taken: list[tuple[dt.datetime, dt.datetime]] | None = None) -> dict[str, tuple[dt.datetime, dt.datetime]]:
    """Greedy: each participant (in order) gets the earliest free slot on the rig within the
    working hours (weekdays) and, if given, their availability. No two slots overlap."""
    if end < start:
        raise InputError("--end: before --start")
    if not 5 <= minutes <= 480:
        raise InputError(f"--session-minutes: {minutes} is out of range; allowed: 5..480")
    h0, h1 = _parse_hours(hours)
    length = dt.timedelta(minutes=minutes)
    busy = sorted(taken or [])
    slots: dict[str, tuple] = {}
    day = start
    candidates = []
    while day <= end:
        if day.weekday() < 5:
            t = dt.datetime.combine(day, h0)
            while t + length <= dt.datetime.combine(day, h1):
                candidates.append((t, t + length))
                t += length
        day += dt.timedelta(days=1)
    for code in codes:
        for a, b in candidates:
            if any(a < y and x < b for x, y in busy):
                continue
            if availability is not None:
                windows = availability.get(code, [])
                if not any(x <= a and b <= y for x, y in windows):
                    continue
            slots[code] = (a, b)
            busy.append((a, b))
            break
    return slots


def to_ics(slots: list[dict], study: str, timezone: str | None = None, title: str = "") -> str:
    """An iCalendar file (RFC 5545, written by the `icalendar` library: escaping of , ; \\ and
    newlines, line folding at 75 octets) with one event per session slot: in the study's time
    zone (with its VTIMEZONE) when the protocol names one, else in floating local times (the
    lab's clock)."""
    import icalendar  # lazy: only for --ics (`status` and every session import this module)

    tz = None
    if timezone is not None:
        tz = ZoneInfo(timezone)
    cal = icalendar.Calendar()
    cal.add("prodid", "-//brainsim-study//studyctl//EN")
    cal.add("version", "2.0")
    cal.add("calscale", "GREGORIAN")
    cal.add("x-wr-calname", study)
    stamp = dt.datetime.now(dt.UTC)
    for s in slots:
        ev = icalendar.Event()
        ev.add("uid", f"{study}-{s['code']}@studyctl")
        ev.add("dtstamp", stamp)
        ev.add("dtstart", dt.datetime.fromisoformat(s["slot_start"]).replace(tzinfo=tz))
        ev.add("dtend", dt.datetime.fromisoformat(s["slot_end"]).replace(tzinfo=tz))
        ev.add("summary", f"{study}: session {s['code']}")
        ev.add("description", (f"{title}\n" if title else "") + "order " + " > ".join(json.loads(s["conditions"])))
        cal.add_component(ev)
    if tz is not None:
        cal.add_missing_timezones()
    return cal.to_ical().decode()


def assign_order(store: Store, protocol, code: str) -> list[str]:
    """The participant's condition order: the stored one, else the next Williams row. With
    groups (design.groups), the rows are counted within the participant's group, so that each
    group is balanced on its own."""
    stored = roster.stored_order(store, code)
    if stored:
        return json.loads(stored)
    group = group_of(store, protocol, code)
    # with groups, the same group: its members' rows only
    completed = roster.completed_orders(store, protocol.groups, group)
    assigned = roster.assigned_orders(store, protocol.groups, group)
    k = next_order(protocol.conditions, completed, assigned)
    order = [protocol.conditions[i] for i in williams(len(protocol.conditions))[k]]
    # plain SQL, so the caller's transaction (if any) holds it
    roster.save_order(store.db.conn, code, k, json.dumps(order))
    return order


def schedule_study(db: str | Path, start: str, end: str, hours: str = "09:00-17:00", minutes: int = 45,
                   availability: str | Path | None = None, ics: str | Path | None = None, dry_run: bool = False,
                   today: dt.date | None = None, force: bool = False) -> list[dict]:
    """Slots and counterbalanced orders for every waiting participant, all stored or none
    (`dry_run`: none, the proposal is returned); `ics`, a calendar of the slots, is refused
    before anything is stored where it exists (unless `force`), and written whole or not at all."""
    if ics and not dry_run:
        refuse_existing([ics], force, inputs={"--db": db, "--availability": availability}, option="--ics")
    try:
        d0, d1 = dt.date.fromisoformat(start), dt.date.fromisoformat(end)
    except ValueError:
        raise InputError("--start/--end: dates must be YYYY-MM-DD") from None
    today = today or dt.date.today()
    if d0 < today:
        raise InputError(f"--start: {d0} is in the past; allowed: today ({today}) or later")
    if (d1 - d0).days > 366:
        raise InputError(f"--end: {d1} is more than a year after --start; allowed: at most 366 days")
    avail = read_availability(availability) if availability else None
    with Store(db) as store:
        protocol = store.protocol()
        codes = roster.participant_codes(store)
        if avail is not None and set(avail) - codes:
            raise InputError(f"{availability}: unknown participant {sorted(set(avail) - codes)[0]!r}")
        # people who still need the rig: no slot, not withdrawn, no finished session, no answers from paper
        waiting = roster.waiting_codes(store)
        if not waiting:
            raise InputError("nobody is waiting for a slot (every person has one, has finished, or withdrew)")
        taken = [(dt.datetime.fromisoformat(r["slot_start"]), dt.datetime.fromisoformat(r["slot_end"]))
                 for r in roster.taken_slots(store)]
        if d0 == today:  # the part of today that has passed is taken too
            taken.append((dt.datetime.combine(today, dt.time(0)), dt.datetime.now().replace(second=0, microsecond=0)))
        slots = allocate(waiting, d0, d1, hours, minutes, avail, taken)
        if not slots:
            why = "their availability" if avail is not None else "free rig time"
            raise InputError(f"no slot for any of the {len(waiting)} waiting participants: {start}..{end}, weekdays {hours}, "
                             f"{minutes} min each, has no {why} left; widen --start/--end or --hours")
        with store.transaction(dry_run) as conn:
            for code in waiting:
                assign_order(store, protocol, code)  # counterbalanced order, kept with the slot
                if code in slots:
                    a, b = slots[code]
                    roster.set_slot(conn, code, a.isoformat(), b.isoformat())
            out = roster.schedule_rows(store)
            if ics and not dry_run:
                write_file(ics, to_ics([r for r in out if r["slot_start"]], protocol.name, protocol.timezone, protocol.title), force,
                           inputs={"--db": db, "--availability": availability}, option="--ics")
        return out

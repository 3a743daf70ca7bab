"""`studyctl session` (and its hidden alias `sessions`), `studyctl replay` and `studyctl synth`:
running sessions, playing a stored trial back, synthetic participants."""

from __future__ import annotations

from pathlib import Path

import click

from sim.text import counted
from studyctl.cli.common import (
    DB,
    DEVICES,
    FORCE,
    FRAMES_EXPECTED,
    FRAMES_OWN,
    FULLSCREEN,
    JSON,
    SCHEDULER,
    SEED,
    Finite,
    OutDir,
    _console,
    _Group,
    _listing,
    _print_json,
    _with_progress,
    say_replaced,
    staged,
)


@click.group(cls=_Group)
def session():
    """Run sessions."""


@session.command("run")
@DB
@click.option("--participant", required=True, help="The participant's code, e.g. P01.")
@click.option("--device", type=click.Choice(["simulated", "mouse", "openhaptics"]), default="simulated", show_default=True,
              help="mouse: pilot a session without hardware (needs --view window).")
@click.option("--synthetic", is_flag=True, help="A synthetic participant answers (data labelled synthetic).")
@click.option("--resume", is_flag=True, help="Continue an interrupted session after its last committed trial.")
@click.option("--time-scale", type=Finite(min=0.0, max=1000.0), default=None, help="1 = real time (default for people); synthetic default 0 = as fast as possible.")
@click.option("--view", type=click.Choice(["none", "window"]), default=None,
              help="The participant view (default: window for a person in real time, else none).")
@click.option("--answers", "answer_with", type=click.Choice(["terminal", "window"]), default="terminal", show_default=True,
              help="Where a person answers the questionnaire (window: keys and the mouse; free text stays in the terminal).")
@click.option("--seed", type=SEED, default=None, help="A synthetic participant's seed  [default: 0; on --resume, the session's]")
@FULLSCREEN
@DEVICES
@JSON
def session_run(db, participant, device, synthetic, resume, time_scale, view, answer_with, seed, fullscreen, device_names, as_json):
    """Training, then each condition in the assigned order: trials, then the questionnaire."""
    from studyctl.session.run import run_session

    if view is None:
        view = "window" if not synthetic and (time_scale is None or time_scale > 0) else "none"
    if fullscreen and view != "window":
        raise click.UsageError("--fullscreen needs --view window")
    out = run_session(db, participant, device, synthetic, resume, time_scale, seed=seed, progress=lambda m: click.echo(m, err=True),
                      view=view, answer_with=answer_with, device_names=device_names, fullscreen=fullscreen)
    if as_json:
        _print_json(out)
        return
    click.echo(f"{out['participant']}'s session complete (session {out['session']} of the study): conditions {' > '.join(out['order'])}, {counted(out['answers'], 'answer')}"
               + (" (SYNTHETIC)" if out["synthetic"] else ""))


@session.command("list")
@DB
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def session_list(db, as_json):
    """Every session: participant, state, device, person or synthetic, trials and answers."""
    from studyctl.participants import list_sessions

    _listing(list_sessions(db), as_json, db, "sessions", ["session", "code", "status", "device", "kind", "started_at", "finished_at", "trials", "answers"])


sessions_alias = _Group("sessions", commands={"list": session_list}, help="Alias: `sessions list` is `session list`.", hidden=True)


@click.command("replay", cls=click.Command)
@DB
@click.option("--session", "session_id", type=click.IntRange(1, 2**63 - 1), required=True, help="The session's number in the study (`session list`).")
@click.option("--trial", type=click.IntRange(1, 10_000), required=True, help="The session's K-th trial, in the order run (1 = the first).")
@click.option("--view", type=click.Choice(["none", "window"]), default="none", show_default=True, help="window: play it back in real time.")
@click.option("--frames", "frames_dir", type=OutDir(), default=None, help="Write pictures, the force plot and the trace.")
@FORCE
@FULLSCREEN
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def replay_cmd(db, session_id, trial, view, frames_dir, force, fullscreen, as_json):
    """Play a stored trial back: its recorded hand motion through the same model and scene."""
    from studyctl.session.trial_replay import replay_trial

    if fullscreen and view != "window":
        raise click.UsageError("--fullscreen needs --view window")
    # refused before the replay
    target = staged(frames_dir, force, folder=True, expect=FRAMES_EXPECTED, inputs={"--db": db}, option="--frames", own=FRAMES_OWN)
    if target:
        with target as tmp:  # the pictures, plot and trace all or none
            out = replay_trial(db, session_id, trial, view=view, frames_dir=tmp, fullscreen=fullscreen)
        say_replaced(target)
    else:
        out = replay_trial(db, session_id, trial, view=view, frames_dir=None, fullscreen=fullscreen)
    if as_json:
        _print_json(out)
        return
    from rich.table import Table

    t = Table(title=f"replay of session {session_id}, trial {trial} (condition {out['label']}, {out['model']})")
    t.add_column("measure")
    t.add_column("value", justify="right")
    t.add_row("ticks", str(out["ticks"]))
    t.add_row("mode", out["mode"])
    t.add_row("largest force difference from the recording (N)", "-" if out["max_force_difference_n"] is None else f"{out['max_force_difference_n']:.3g}")
    if frames_dir is not None:
        t.add_row("pictures", f"{out['frames']} in {frames_dir}")
    _console().print(t)


@click.command("synth", cls=click.Command)
@DB
@click.option("--participants", type=click.IntRange(1, 1000), default=None, help="How many new synthetic participants (1..1000).")
@click.option("--complete", is_flag=True,
              help="Run the participants an interrupted synth registered without a session, bringing that run to its N.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the new participants' traits and answers (the same seed, the same study).")
@click.option("--jobs", type=click.IntRange(1, 64), default=1, show_default=True, help="Sessions run in parallel processes.")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path), default=None,
              help="Create --db for this protocol when it does not exist (e.g. protocols/brain_pull_2015.toml); without it, --db must exist.")
@click.option("--alongside-people", is_flag=True,
              help="Add synthetic sessions to a study with people registered (its reports then say MIXED DATA); refused otherwise.")
@SCHEDULER
@JSON
def synth_cmd(db, participants, complete, seed, jobs, protocol_file, alongside_people, scheduler, as_json):
    """Run whole sessions with SYNTHETIC participants on the simulator (labelled synthetic).
    After an interrupted run, --complete runs the participants it registered (with their own
    seed), bringing it to its N; new participants are refused until then."""
    from studyctl.synthetic.synth_run import run_synthetic_study

    out = _with_progress("synthetic sessions", lambda p: run_synthetic_study(db, participants, seed, jobs, protocol_file, progress=p,
                                                                             scheduler=scheduler, alongside_people=alongside_people,
                                                                             complete=complete))
    if as_json:
        _print_json(out | {"synthetic": True})
        _warn(out["warnings"])
        return
    if out["created"]:
        click.echo(f"created {db} for the protocol {out['created']}")
    done = out["completed"]
    seeds = ", ".join(str(s) for s in sorted({c["seed"] for c in done}))
    # participants an interrupted run registered get their whole session now: nothing of theirs is resumed
    left = f", {len(done)} left by an interrupted run, run from the start ({', '.join(c['code'] for c in done)}; seed {seeds})" if done else ""
    where = f"on the Dask cluster at {scheduler}" if scheduler else f"{jobs} job{'s' if jobs != 1 else ''}"
    new = f"{out['participants']} new (seed {seed})" if out["participants"] else "0 new"
    click.echo(f"ran {out['ran']} SYNTHETIC session{'s' if out['ran'] != 1 else ''} of {out['protocol']!r}: {new}{left}; "
               f"{out['total_synthetic']} synthetic participant{'s' if out['total_synthetic'] != 1 else ''} with a session in total "
               f"({where}, {out['seconds']:.1f} s)")
    _warn(out["warnings"])


def _warn(lines: list[str]) -> None:
    for line in lines:  # stderr, exit 0: the run succeeded and its data are stored; the reports withhold the tests
        click.echo(f"warning: {line}", err=True)

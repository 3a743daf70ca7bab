"""The `studyctl` command line: parse options, call one library function, print.

Library exceptions (`sim.errors.SimError`, `analysis.errors.StudyError`) become one-line errors
(a file with several problems: one line each) with exit status 1; usage
mistakes are click's (exit status 2). No traceback reaches the user for either.

One module per command group, each imported here and added to the root group `cli`; what they
share (the error handling, output, option types and common options) is in `common`. Commands
import their library (and anything heavy) inside their functions: `studyctl --help` stays fast.
Imports: click, rich, and every layer below (`studyctl`, `analysis`, `sim`).
"""

from __future__ import annotations

import sys

import click

from studyctl.cli import (
    answers,
    bench,
    calibrate,
    devices,
    metrics,
    model,
    participants,
    plan,
    reports,
    sessions,
    simulator,
    study,
)
from studyctl.cli.common import LoadErrorsAsImportErrors, _Group


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="brainsim-study", prog_name="studyctl")
def cli():
    """Haptic brain-surgery simulator: experiments, user studies and reports."""


def main() -> None:
    sys.meta_path.insert(0, LoadErrorsAsImportErrors())  # a broken optional extra: one line, not a traceback
    try:
        cli(prog_name="studyctl")
    except KeyboardInterrupt:  # a further Ctrl-C while the command printed its last line or exited: still one line
        click.echo("Error: interrupted (Ctrl-C) again while ending; what was written is whole", err=True)
        sys.exit(130)


# the order the groups are defined in; `--help` lists them sorted by name (`sessions`: a hidden alias)
for _command in (
    bench.bench, model.model, calibrate.calibrate, simulator.sim, devices.devices,
    study.protocol, study.study, participants.participants, participants.schedule_cmd, study.status_cmd,
    sessions.session, sessions.sessions_alias, sessions.replay_cmd, sessions.synth_cmd, plan.plan_cmd,
    reports.report, answers.answers, reports.export_cmd, metrics.metrics_cmd,
):
    cli.add_command(_command)

"""`studyctl plan`: Monte Carlo power to choose N, and the observer's fairness (null) test."""

from __future__ import annotations

from pathlib import Path

import click

from analysis.errors import InputError
from studyctl.cli.common import (
    DEFAULT_PROTOCOL,
    FORCE,
    SCHEDULER,
    SEED,
    OutFile,
    _console,
    _model_name,
    _print_json,
    _with_progress,
    say_replaced,
    staged,
)


def _range(ctx, param, value):
    try:
        a, b = (int(x) for x in value.split("..")) if ".." in value else (int(value), int(value))
    except ValueError:
        raise click.BadParameter(f"{value!r} is not a number or a range such as 12..60") from None
    if not 3 <= a <= b <= 1000:
        raise click.BadParameter(f"{value!r}: need 3 <= from <= to <= 1000")
    return a, b


@click.command("plan", cls=click.Command)
@click.option("--participants", "span", default=None, callback=lambda c, p, v: None if v is None else _range(c, p, v),
              help="N, or a range of N such as 12..60  [default: 12..60; with --null 35]")
@click.option("--step", type=click.IntRange(1, 100), default=6, show_default=True, help="Participants between the N tried.")
@click.option("--simulations", type=click.IntRange(10, 100000), default=200, show_default=True, help="Simulated studies per N.")
@click.option("--protocol", "protocol_file", type=click.Path(dir_okay=False, path_type=Path),
              default=DEFAULT_PROTOCOL, show_default="the shipped protocols/brain_pull_2015.toml", help="The protocol whose study is simulated.")
@click.option("--seed", type=SEED, default=0, show_default=True, help="Seed of the simulated studies (the same seed, the same table).")
@click.option("--pilots", type=click.IntRange(1, 50), default=4, show_default=True, help="Synthetic pilot runs per model.")
@click.option("--plot", "plot_file", type=OutFile((".png", ".svg", ".pdf")), default=None, help="Write the power curves (PNG, SVG or PDF).")
@FORCE
@click.option("--null", "null", is_flag=True, help="The observer's fairness test: one model under every label; false-positive rates.")
@click.option("--model", "null_model", default=None, help="With --null: the model to repeat  [default: the protocol's first condition]")
@click.option("--jobs", type=click.IntRange(1, 256), default=1, show_default=True, help="Simulated studies run in parallel processes.")
@SCHEDULER
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output (JSON).")
def plan_cmd(span, step, simulations, protocol_file, seed, pilots, plot_file, force, null, null_model, jobs, scheduler, as_json):
    """Monte Carlo power under the SYNTHETIC model, to choose N: of the protocol's primary
    analysis and of each question's test (Cochran's Q, Friedman, the multinomial); with --null,
    the false-positive rate of each when every condition is one model."""
    from analysis.statistics.kinds import primary
    from studyctl.protocol import load_protocol
    from studyctl.synthetic.plan import plot_power, power_table

    target = staged(plot_file, force, inputs={"--protocol": protocol_file}, option="--plot")  # refused before the simulations
    protocol = load_protocol(protocol_file)
    if null:
        ctx = click.get_current_context()
        for name, opt in (("step", "--step"), ("plot_file", "--plot")):
            if ctx.get_parameter_source(name) is not click.core.ParameterSource.DEFAULT:
                raise InputError(f"{opt}: not with --null (it reports false-positive rates at one N)")
        _plan_null(protocol, span, simulations, seed, pilots, null_model, as_json, {"jobs": jobs, "scheduler": scheduler})
        return
    if null_model is not None:
        raise InputError("--model: only with --null")
    span = span or (12, 60)
    ns = list(range(span[0], span[1] + 1, step))
    table = _with_progress("simulated studies", lambda p: power_table(protocol, ns, simulations, seed, pilots, progress=p,
                                                                           jobs=jobs, scheduler=scheduler))
    if target:
        with target as tmp:
            plot_power(table, tmp)
        say_replaced(target)
    if as_json:
        _print_json({"synthetic": True, "primary": primary(protocol).as_dict(), "rows": table.to_dict(orient="records")})
        return
    from rich.table import Table

    names = list(dict.fromkeys(table["item"]))
    wide = table.pivot(index="n", columns="item", values="power")[names]
    t = Table(title=f"SYNTHETIC power (p < 0.05), {simulations} simulated studies per N; primary: {primary(protocol).text}")
    t.add_column("N", justify="right")
    for q in names:
        t.add_column(q, justify="right")
    for n, row in wide.iterrows():
        t.add_row(str(n), *(f"{v:.2f}" for v in row))
    _console().print(t)
    if plot_file:
        click.echo(f"plot: {plot_file}")


def _plan_null(protocol, span, simulations, seed, pilots, model, as_json, where: dict) -> None:
    from analysis.statistics.kinds import primary
    from studyctl.synthetic.plan import null_table

    if span is not None and span[0] != span[1]:
        raise InputError("--participants: with --null give one N (e.g. 35), not a range")
    if model is not None:
        model = _model_name(model)
        if model not in protocol.conditions:
            raise InputError(f"--model: {model!r} is not a condition of {protocol.name}; allowed: {', '.join(protocol.conditions)}")
    n = span[0] if span else 35
    table = _with_progress("simulated studies", lambda p: null_table(protocol, model, n, simulations, seed, pilots, progress=p, **where))
    if as_json:
        _print_json({"synthetic": True, "null": True, "model": table["model"].iloc[0], "participants": n, "primary": primary(protocol).as_dict(),
                     "items": table[["item", "false_positive_rate", "mc_error", "simulations", "alpha"]].to_dict(orient="records")})
        return
    from rich.table import Table

    t = Table(title=f"SYNTHETIC null test: {table['model'].iloc[0]} under every label, N = {n}, {simulations} simulated studies")
    for c in ("question", "false-positive rate", "alpha", "Monte Carlo s.e."):
        t.add_column(c, justify="right" if c != "question" else "left")
    for _, r in table.iterrows():
        t.add_row(r["item"], f"{r['false_positive_rate']:.3f}", f"{r['alpha']:.2f}", f"{r['mc_error']:.3f}")
    _console().print(t)

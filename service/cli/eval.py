"""``firetrack eval``: score the algorithms on recordings with ground truth (one module per verb)."""
from __future__ import annotations

import typer

from service.cli.eval_ahrs import eval_ahrs
from service.cli.eval_ble import eval_ble
from service.cli.eval_floors import eval_floors
from service.cli.eval_ipin import eval_ipin
from service.cli.eval_steps import eval_steps
from service.cli.eval_zupt import eval_zupt

app = typer.Typer(help="Score algorithms on recordings with ground truth.", no_args_is_help=True)
app.command("ahrs")(eval_ahrs)
app.command("steps")(eval_steps)
app.command("ipin")(eval_ipin)
app.command("floors")(eval_floors)
app.command("zupt")(eval_zupt)
app.command("ble")(eval_ble)

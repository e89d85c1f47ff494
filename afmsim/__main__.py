"""``python -m afmsim`` runs the command-line interface."""

from afmsim.cli import app

app(prog_name="afmsim")

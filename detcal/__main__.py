"""``python -m detcal``: the command line."""

from detcal.cli import run

run()

"""``python -m flocking`` is the ``flocking`` command."""

from .cli import main

main()

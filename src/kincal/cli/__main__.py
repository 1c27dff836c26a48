"""``python -m kincal.cli``: the ``kincal`` command."""

from kincal.cli import main

main()

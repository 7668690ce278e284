"""``python -m drivebus.cli``: the same as the ``drivebus`` command."""

from drivebus.cli import main

main()

"""``python -m tankctl``."""

from tankctl.cli import main

main()

"""``python -m tankctl``."""

from tankctl.entry import main

main()

"""The ``tankctl`` console script and ``python -m tankctl``: the CLI with the cyclic garbage
collector off while it imports.

A command's imports (typer, the command's module, asyncua, the config models) allocate a few
hundred thousand objects, none of them garbage; each full generation-0 collection on the way
walks them again. Off, ``import tankctl.cli`` plus an operator command's modules take about 10 %
less CPU (decision 0044). :meth:`tankctl.cli.TankctlGroup.resolve_command` turns it back on
(:func:`imports_done`) once the command to run is imported, so a long-lived command (a tier,
``up``) collects as usual; a process that only prints ``--help`` or a usage error exits with it
off.
"""

from __future__ import annotations

import gc


def imports_done() -> None:
    """The command is imported: collect again, and leave what the imports made out of every
    later collection (``gc.freeze``: module-level objects live as long as the process)."""
    if not gc.isenabled():
        gc.freeze()
        gc.enable()


def main() -> None:
    """Console-script entry point: :func:`tankctl.cli.main` with the collector off meanwhile."""
    gc.disable()
    try:
        from tankctl.cli import main as cli_main
    except BaseException:
        gc.enable()
        raise
    cli_main()

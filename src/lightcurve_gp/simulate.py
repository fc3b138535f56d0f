"""``python -m lightcurve_gp.simulate``: the command of :mod:`lightcurve_gp.commands.simulate`.

The command's imports (torch: seconds) run inside the interrupt handler, so Ctrl-C while they load is the one line
and exit code 130 of every interrupt (:mod:`lightcurve_gp.commands.common`), not a traceback.
"""

import sys

if __name__ == "__main__":
    try:
        from lightcurve_gp.commands.common import exit_process
        from lightcurve_gp.commands.simulate import main
    except KeyboardInterrupt:
        print("interrupted; nothing written", file=sys.stderr)
        sys.exit(130)
    exit_process(main())

"""Entry point of the frozen application (PyInstaller): the ``impress`` command.

The bundle's executable behaves like the installed console script: ``impress`` opens the window,
``impress simulate ...``, ``impress process ...`` etc. run the subcommands.
"""

import multiprocessing
import sys

if __name__ == "__main__":
    # the simulator renders in spawned worker processes: a frozen child must run the worker,
    # not the command line again
    multiprocessing.freeze_support()
    from impress_gui.cli import main

    sys.exit(main())

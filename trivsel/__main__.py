import os
import sys

from .cli import main

code = main()
if code == 130:
    # Interrupted and reported: end with status 130 now.  Under `python -m`, an interrupt
    # that arrived while a module was being imported can make the interpreter end itself
    # by SIGINT (status -2) at exit, after the one-line message.
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(130)
sys.exit(code)

"""``python -m cnc_bridge.cnc_emulator``: the command (see :mod:`.cli`)."""
import sys

from cnc_bridge.cnc_emulator.cli import main

sys.exit(main())

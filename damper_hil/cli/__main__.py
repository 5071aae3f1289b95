"""``python -m damper_hil.cli``."""

import sys

from damper_hil.cli import main

sys.exit(main())

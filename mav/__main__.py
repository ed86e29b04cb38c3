"""`python -m mav` runs the onboard flight stack process (same as `python -m mav.onboard`)."""

import sys

from mav.onboard import main

sys.exit(main())

import sys

from mav.onboard.process import main

sys.exit(main())

"""`python -m companion`: the companion application (see companion.app)."""

import sys

from companion.app import main

sys.exit(main())

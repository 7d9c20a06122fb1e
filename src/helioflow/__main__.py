"""`python -m helioflow <step>`: the same as the `helioflow` command."""

import sys

from .cli import main

sys.exit(main())

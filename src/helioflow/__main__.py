"""`python -m helioflow <step>`: the same as the `helioflow` command."""

import sys

from helioflow.cli import main

sys.exit(main())

"""``python -m toolkit`` runs the command line."""

import sys

from shape_toolkit.cli import main

sys.exit(main())

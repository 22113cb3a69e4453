"""``python -m elastocap`` runs the command line."""

import sys

from elastocap.cli import main

sys.exit(main())

"""``python -m elastocap`` runs the command line."""

import sys

from elastocap.pipeline.cli import main

sys.exit(main())

"""``python -m bracketry`` runs the CLI."""

import sys

from bracketry.cli import main

sys.exit(main())

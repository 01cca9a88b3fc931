"""``python -m evaluation.florence``: :func:`evaluation.florence.cli.main`."""
import sys

from .cli import main

sys.exit(main())
